/* The static rANS coder of FORMAT.md I.6.1 in C: the same stream bytes as the pure-Python reference in
 * rans.py, about 1,000x faster.  Integer arithmetic only (uint32 state, uint64 never needed), so every
 * machine produces and accepts the same bytes.
 *
 * Both functions take frequency tables that rans.py has already validated (parse_table / normalize_counts);
 * they re-check the sum and every symbol index anyway, so no input can make them read or write out of
 * bounds.  Work is bounded by the declared symbol count: each decoded symbol reads at most 2 stream bytes
 * and each encoded symbol writes at most 2.  The GIL is released while coding.
 *
 *   decode(stream, freqs_u32, out_u16) -> (symbols_decoded, stream_pos, final_state)
 *   decode_mapped(...): decode, symbols -> codes -> float32 by table in the same pass (see below)
 *   encode(symbols_u16, freqs_u32) -> bytes, or None if a symbol has frequency 0 or lies outside the table
 *   column_histograms(codes_u8, cols, size, out_i64) -> None: out[(k % cols) * size + codes[k]] += 1, or
 *       ValueError if a code is >= size (the writer's one counting pass, for its median and both tables)
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <string.h>

#define PROB_BITS 14
#define PROB_SCALE (1u << PROB_BITS)
#define STATE_LOWER (1u << 23)
#define UPPER_SHIFT (23 - PROB_BITS + 8) /* x_max(s) = f[s] << 17 */
#define MAX_ALPHABET 65536

/* freqs_u32 -> cum[]; returns 0 unless the table sums to PROB_SCALE with every entry <= PROB_SCALE. */
static int build_cum(const uint32_t *freqs, Py_ssize_t alphabet, uint32_t *cum) {
    uint64_t acc = 0;
    for (Py_ssize_t s = 0; s < alphabet; s++) {
        if (freqs[s] > PROB_SCALE) return 0;
        cum[s] = (uint32_t)acc;
        acc += freqs[s];
    }
    return acc == PROB_SCALE;
}

static int table_arg(Py_buffer *fb, Py_ssize_t *alphabet) {
    if (fb->len % 4 || fb->len == 0 || fb->len / 4 > MAX_ALPHABET) {
        PyErr_SetString(PyExc_ValueError, "freqs must be 1..65536 uint32 values");
        return 0;
    }
    *alphabet = fb->len / 4;
    return 1;
}

/* Decoder tables: cum[] and the slot -> symbol map (caller frees both with PyMem_Free). */
static int decoder_tables(Py_buffer *fb, Py_buffer *sb, uint32_t **cum, uint16_t **slot_sym) {
    Py_ssize_t alphabet;
    *cum = NULL;
    *slot_sym = NULL;
    if (!table_arg(fb, &alphabet)) return 0;
    if (sb->len < 4) {
        PyErr_SetString(PyExc_ValueError, "stream shorter than its initial state");
        return 0;
    }
    const uint32_t *freqs = (const uint32_t *)fb->buf;
    *cum = PyMem_Malloc(sizeof(uint32_t) * (size_t)alphabet);
    *slot_sym = PyMem_Malloc(sizeof(uint16_t) * PROB_SCALE);
    if (!*cum || !*slot_sym) {
        PyErr_NoMemory();
        return 0;
    }
    if (!build_cum(freqs, alphabet, *cum)) {
        PyErr_SetString(PyExc_ValueError, "frequency table does not sum to 2^14");
        return 0;
    }
    for (Py_ssize_t s = 0; s < alphabet; s++)
        for (uint32_t k = 0; k < freqs[s]; k++) (*slot_sym)[(*cum)[s] + k] = (uint16_t)s;
    return 1;
}

static uint32_t initial_state(const uint8_t *data) {
    return (uint32_t)data[0] | (uint32_t)data[1] << 8 | (uint32_t)data[2] << 16 | (uint32_t)data[3] << 24;
}

/* One decoding step of FORMAT.md I.6.1: symbol s from state x, then renormalise from data[pos..end);
 * `break`s out of the caller's loop (before storing symbol i) when the stream runs out. */
#define DECODE_STEP(s)                                                  \
    uint32_t slot = x & (PROB_SCALE - 1);                               \
    uint16_t s = slot_sym[slot];                                        \
    x = freqs[s] * (x >> PROB_BITS) + slot - cum[s];                    \
    if (x < STATE_LOWER) {                                              \
        if (pos >= end) break;                                          \
        x = (x << 8) | data[pos++];                                     \
        if (x < STATE_LOWER) {                                          \
            if (pos >= end) break;                                      \
            x = (x << 8) | data[pos++];                                 \
        }                                                               \
    }

static PyObject *rans_decode(PyObject *self, PyObject *args) {
    Py_buffer sb, fb, ob;
    if (!PyArg_ParseTuple(args, "y*y*w*", &sb, &fb, &ob)) return NULL;
    PyObject *result = NULL;
    uint32_t *cum = NULL;
    uint16_t *slot_sym = NULL;
    if (!decoder_tables(&fb, &sb, &cum, &slot_sym)) goto done;
    if (ob.len % 2) {
        PyErr_SetString(PyExc_ValueError, "out must be a uint16 buffer");
        goto done;
    }
    const uint32_t *freqs = (const uint32_t *)fb.buf;
    const uint8_t *data = (const uint8_t *)sb.buf;
    const Py_ssize_t end = sb.len, count = ob.len / 2;
    uint16_t *out = (uint16_t *)ob.buf;
    uint32_t x = initial_state(data);
    Py_ssize_t pos = 4, i = 0;
    Py_BEGIN_ALLOW_THREADS
    for (; i < count; i++) {
        DECODE_STEP(s)
        out[i] = s;
    }
    Py_END_ALLOW_THREADS
    result = Py_BuildValue("(nnk)", i, pos, (unsigned long)x);
done:
    PyMem_Free(cum);
    PyMem_Free(slot_sym);
    PyBuffer_Release(&sb);
    PyBuffer_Release(&fb);
    PyBuffer_Release(&ob);
    return result;
}

/* decode + symbol -> code (prediction 0 or 1) + dequantization by table, in one pass:
 *   code = s (no centre) or s + centre[c] - top (centre given), which must lie in 0..top, else `bad` is
 *   set (decoding goes on, so stream errors are reported first, as by the Python reference);
 *   out[k] = lut[colbase[c] + code] with c = k mod cols.
 * Returns (symbols_decoded, stream_pos, final_state, bad). */
static PyObject *rans_decode_mapped(PyObject *self, PyObject *args) {
    Py_buffer sb, fb, ob, cb, lb, zb;
    Py_ssize_t cols;
    int top;
    if (!PyArg_ParseTuple(args, "y*y*w*ny*y*y*i", &sb, &fb, &ob, &cols, &cb, &lb, &zb, &top)) return NULL;
    PyObject *result = NULL;
    uint32_t *cum = NULL;
    uint16_t *slot_sym = NULL;
    if (!decoder_tables(&fb, &sb, &cum, &slot_sym)) goto done;
    const Py_ssize_t lut_len = lb.len / 4;
    if (ob.len % 4 || cols < 1 || (ob.len / 4) % cols || cb.len != 4 * cols || lb.len % 4 || top < 0 ||
        top > 255 || (zb.len != 0 && zb.len != cols)) {
        PyErr_SetString(PyExc_ValueError, "decode_mapped: shapes do not match");
        goto done;
    }
    const uint32_t *colbase = (const uint32_t *)cb.buf;
    for (Py_ssize_t c = 0; c < cols; c++) {
        if ((Py_ssize_t)colbase[c] + top >= lut_len) {
            PyErr_SetString(PyExc_ValueError, "decode_mapped: a column's table runs past the end");
            goto done;
        }
    }
    const uint32_t *freqs = (const uint32_t *)fb.buf;
    const float *lut = (const float *)lb.buf;
    const uint8_t *centre = zb.len ? (const uint8_t *)zb.buf : NULL;
    const uint8_t *data = (const uint8_t *)sb.buf;
    const Py_ssize_t end = sb.len, count = ob.len / 4;
    float *out = (float *)ob.buf;
    uint32_t x = initial_state(data);
    Py_ssize_t pos = 4, i = 0, c = 0;
    int bad = 0;
    Py_BEGIN_ALLOW_THREADS
    for (; i < count; i++) {
        DECODE_STEP(s)
        int code = centre ? (int)s + (int)centre[c] - top : (int)s;
        if (code < 0 || code > top) {
            bad = 1;
            code = 0;
        }
        out[i] = lut[colbase[c] + (uint32_t)code];
        if (++c == cols) c = 0;
    }
    Py_END_ALLOW_THREADS
    result = Py_BuildValue("(nnki)", i, pos, (unsigned long)x, bad);
done:
    PyMem_Free(cum);
    PyMem_Free(slot_sym);
    PyBuffer_Release(&sb);
    PyBuffer_Release(&fb);
    PyBuffer_Release(&ob);
    PyBuffer_Release(&cb);
    PyBuffer_Release(&lb);
    PyBuffer_Release(&zb);
    return result;
}

static PyObject *rans_encode(PyObject *self, PyObject *args) {
    Py_buffer yb, fb;
    if (!PyArg_ParseTuple(args, "y*y*", &yb, &fb)) return NULL;
    PyObject *result = NULL;
    uint32_t *cum = NULL;
    uint8_t *buf = NULL;
    Py_ssize_t alphabet;
    if (!table_arg(&fb, &alphabet)) goto done;
    if (yb.len % 2) {
        PyErr_SetString(PyExc_ValueError, "symbols must be a uint16 buffer");
        goto done;
    }
    const uint32_t *freqs = (const uint32_t *)fb.buf;
    cum = PyMem_Malloc(sizeof(uint32_t) * (size_t)alphabet);
    if (!cum) {
        PyErr_NoMemory();
        goto done;
    }
    if (!build_cum(freqs, alphabet, cum)) {
        PyErr_SetString(PyExc_ValueError, "frequency table does not sum to 2^14");
        goto done;
    }
    const uint16_t *sym = (const uint16_t *)yb.buf;
    const Py_ssize_t count = yb.len / 2;
    if (count > (PY_SSIZE_T_MAX - 4) / 2) {
        PyErr_NoMemory();
        goto done;
    }
    const size_t cap = 2 * (size_t)count + 4; /* each symbol emits at most 2 bytes, plus the final state */
    buf = PyMem_Malloc(cap);
    if (!buf) {
        PyErr_NoMemory();
        goto done;
    }
    uint8_t *p = buf + cap; /* bytes are written backwards, so the stream reads forwards */
    uint32_t x = STATE_LOWER;
    int bad = 0;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t i = count - 1; i >= 0; i--) {
        uint16_t s = sym[i];
        if (s >= alphabet || freqs[s] == 0) {
            bad = 1;
            break;
        }
        uint32_t f = freqs[s], x_max = f << UPPER_SHIFT;
        while (x >= x_max) {
            *--p = (uint8_t)(x & 0xFF);
            x >>= 8;
        }
        x = ((x / f) << PROB_BITS) + (x % f) + cum[s];
    }
    Py_END_ALLOW_THREADS
    if (bad) {
        result = Py_NewRef(Py_None);
        goto done;
    }
    p -= 4;
    p[0] = (uint8_t)x;
    p[1] = (uint8_t)(x >> 8);
    p[2] = (uint8_t)(x >> 16);
    p[3] = (uint8_t)(x >> 24);
    result = PyBytes_FromStringAndSize((const char *)p, (Py_ssize_t)(buf + cap - p));
done:
    PyMem_Free(cum);
    PyMem_Free(buf);
    PyBuffer_Release(&yb);
    PyBuffer_Release(&fb);
    return result;
}

static PyObject *column_histograms(PyObject *self, PyObject *args) {
    Py_buffer cb, ob;
    Py_ssize_t cols, size;
    if (!PyArg_ParseTuple(args, "y*nnw*", &cb, &cols, &size, &ob)) return NULL;
    PyObject *result = NULL;
    if (cols < 1 || size < 1 || size > 256 || cb.len % cols || ob.len != (Py_ssize_t)sizeof(int64_t) * cols * size) {
        PyErr_SetString(PyExc_ValueError, "column_histograms: shapes do not match");
        goto done;
    }
    const uint8_t *codes = (const uint8_t *)cb.buf;
    int64_t *hist = (int64_t *)ob.buf;
    const Py_ssize_t rows = cb.len / cols;
    int bad = 0;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t r = 0; r < rows && !bad; r++) {
        const uint8_t *row = codes + r * cols;
        for (Py_ssize_t c = 0; c < cols; c++) {
            if (row[c] >= size) {
                bad = 1;
                break;
            }
            hist[c * size + row[c]]++;
        }
    }
    Py_END_ALLOW_THREADS
    if (bad) {
        PyErr_SetString(PyExc_ValueError, "column_histograms: a code is outside 0 .. size - 1");
        goto done;
    }
    result = Py_NewRef(Py_None);
done:
    PyBuffer_Release(&cb);
    PyBuffer_Release(&ob);
    return result;
}

static PyMethodDef methods[] = {
    {"decode", rans_decode, METH_VARARGS,
     "decode(stream, freqs_u32, out_u16) -> (symbols_decoded, stream_pos, final_state)"},
    {"decode_mapped", rans_decode_mapped, METH_VARARGS,
     "decode_mapped(stream, freqs_u32, out_f32, cols, colbase_u32, lut_f32, centre_u8_or_empty, top)"
     " -> (symbols_decoded, stream_pos, final_state, bad_code)"},
    {"encode", rans_encode, METH_VARARGS,
     "encode(symbols_u16, freqs_u32) -> stream bytes, or None if a symbol has frequency 0"},
    {"column_histograms", column_histograms, METH_VARARGS,
     "column_histograms(codes_u8, cols, size, out_i64): count code v of column c into out[c * size + v]"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_rans_native",
                                    "The rANS coder of FORMAT.md I.6.1 in C (see rans.py).", -1, methods};

PyMODINIT_FUNC PyInit__rans_native(void) { return PyModule_Create(&module); }
