"""Archives over fsspec: the memory file system and a Range-capable HTTP server on 127.0.0.1.

Reading one scene must fetch only the tail footer, the index and that scene's payload.
"""

import re
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import fsspec
import pytest

from vt4dcodec.archive import ArchiveWriter, open_archive, verify_archive
from vt4dcodec.archive.layout import FOOTER_SIZE, HEADER_SIZE
from vt4dcodec.data.archive_dataset import resolve_shards

from .helpers import payload_for, scene_record

N = 40


@pytest.fixture(scope="module")
def archive_bytes(tmp_path_factory) -> bytes:
    path = tmp_path_factory.mktemp("remote") / "r.vt4da"
    with ArchiveWriter(path, durable=False) as w:
        for i in range(N):
            w.append(f"k{i:03d}", payload_for(f"k{i}", 2000 + i), validate=False)
        w.append("real", scene_record(1))
    return path.read_bytes()


def _expected_cost(ar, key) -> int:
    # FORMAT.md Part II section 7: opening reads the header (preamble + slots), the footer, the index
    return HEADER_SIZE + FOOTER_SIZE + ar.commit.index_length + ar.entry(key).length


def test_memory_filesystem_reads_only_needed_ranges(archive_bytes):
    fs = fsspec.filesystem("memory")
    fs.pipe("/vt4d-test/r.vt4da", archive_bytes)
    try:
        with open_archive("memory://vt4d-test/r.vt4da") as ar:
            assert ar.read_bytes("k007") == payload_for("k7", 2007)
            assert ar.source.reads == 4
            assert ar.source.bytes_read == _expected_cost(ar, "k007")
        verify_archive("memory://vt4d-test/r.vt4da", records=False)
        assert resolve_shards("memory://vt4d-test/*.vt4da") == ["memory://vt4d-test/r.vt4da"]
    finally:
        fs.rm("/vt4d-test", recursive=True)


class _RangeHandler(BaseHTTPRequestHandler):
    """Serves one in-memory file with single byte ranges (RFC 9110), counting bytes sent.

    The counters are updated under a lock *before* the body is written: once the client holds the
    bytes, the count already includes them (counting after the write raced with the test's assert).
    """

    data = b""
    sent = 0
    requests = 0
    lock = threading.Lock()

    def log_message(self, *args):
        pass

    def _span(self):
        m = re.fullmatch(r"bytes=(\d*)-(\d*)", self.headers.get("Range", ""))
        n = len(self.data)
        if not m:
            return None
        a, b = m.groups()
        if a == "":
            return max(0, n - int(b)), n - 1
        return int(a), min(int(b), n - 1) if b else n - 1

    def do_HEAD(self):
        self.send_response(200)
        self.send_header("Content-Length", str(len(self.data)))
        self.send_header("Accept-Ranges", "bytes")
        self.end_headers()

    def do_GET(self):
        span = self._span()
        cls = type(self)
        if span is None:
            body, code = self.data, 200
        else:
            body, code = self.data[span[0]: span[1] + 1], 206
        self.send_response(code)
        if code == 206:
            self.send_header("Content-Range", f"bytes {span[0]}-{span[1]}/{len(self.data)}")
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Accept-Ranges", "bytes")
        self.end_headers()
        with cls.lock:
            cls.requests += 1
            cls.sent += len(body)
        self.wfile.write(body)


@pytest.fixture()
def http_url(archive_bytes):
    handler = type("H", (_RangeHandler,), {"data": archive_bytes, "sent": 0, "requests": 0})
    server = ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/r.vt4da", handler
    finally:
        server.shutdown()
        server.server_close()
        thread.join()


def test_http_range_reads_fetch_only_footer_index_and_record(http_url):
    url, handler = http_url
    with open_archive(url) as ar:
        assert ar.read_bytes("k031") == payload_for("k31", 2031)
        assert ar.open_scene("real").static_shape == (16, 8)
        expected = _expected_cost(ar, "k031") + ar.entry("real").length
        assert ar.source.bytes_read == expected
    assert handler.sent == expected  # the server agrees: nothing else crossed the wire
    assert handler.requests == 5
