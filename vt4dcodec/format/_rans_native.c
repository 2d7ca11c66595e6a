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
 *   encode(jobs) -> [bytes, or None if a symbol has frequency 0 or lies outside the table] for 1-2 streams
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

/* A stream to decode + map: symbol -> code (prediction 0 or 1) -> float32 by table, in one pass:
 *   code = s (no centre) or s + centre[c] - top (centre given), which must lie in 0..top, else `bad` is
 *   set (decoding goes on, so stream errors are reported first, as by the Python reference);
 *   out[k] = lut[colbase[c] + code] with c = k mod cols. */
typedef struct {
    Py_buffer sb, fb, ob, cb, lb, zb;
    int nbuf; /* how many of the buffers above are held */
    uint32_t *cum;
    uint16_t *slot_sym;
    const uint32_t *freqs, *colbase;
    const float *lut;
    const uint8_t *centre, *data;
    float *out;
    Py_ssize_t end, pos, count, i, cols, c;
    uint32_t x;
    int top, bad;
} mapped_job;

static void job_release(mapped_job *j) {
    Py_buffer *bufs[6] = {&j->sb, &j->fb, &j->ob, &j->cb, &j->lb, &j->zb};
    for (int k = 0; k < j->nbuf; k++) PyBuffer_Release(bufs[k]);
    j->nbuf = 0;
    PyMem_Free(j->cum);
    PyMem_Free(j->slot_sym);
    j->cum = NULL;
    j->slot_sym = NULL;
}

/* Parse (stream, freqs_u32, out_f32, cols, colbase_u32, lut_f32, centre_u8_or_empty, top); 0 on error. */
static int job_setup(mapped_job *j, PyObject *spec) {
    memset(j, 0, sizeof(*j));
    if (!PyTuple_Check(spec) || !PyArg_ParseTuple(spec, "y*y*w*ny*y*y*i", &j->sb, &j->fb, &j->ob, &j->cols, &j->cb,
                                                  &j->lb, &j->zb, &j->top)) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "decode_mapped: each job must be a tuple");
        return 0;
    }
    j->nbuf = 6;
    if (!decoder_tables(&j->fb, &j->sb, &j->cum, &j->slot_sym)) return 0;
    const Py_ssize_t lut_len = j->lb.len / 4;
    if (j->ob.len % 4 || j->cols < 1 || (j->ob.len / 4) % j->cols || j->cb.len != 4 * j->cols || j->lb.len % 4 ||
        j->top < 0 || j->top > 255 || (j->zb.len != 0 && j->zb.len != j->cols)) {
        PyErr_SetString(PyExc_ValueError, "decode_mapped: shapes do not match");
        return 0;
    }
    j->colbase = (const uint32_t *)j->cb.buf;
    for (Py_ssize_t c = 0; c < j->cols; c++) {
        if ((Py_ssize_t)j->colbase[c] + j->top >= lut_len) {
            PyErr_SetString(PyExc_ValueError, "decode_mapped: a column's table runs past the end");
            return 0;
        }
    }
    j->freqs = (const uint32_t *)j->fb.buf;
    j->lut = (const float *)j->lb.buf;
    j->centre = j->zb.len ? (const uint8_t *)j->zb.buf : NULL;
    j->data = (const uint8_t *)j->sb.buf;
    j->end = j->sb.len;
    j->count = j->ob.len / 4;
    j->out = (float *)j->ob.buf;
    j->x = initial_state(j->data);
    j->pos = 4;
    return 1;
}

/* Decode and store symbol j->i; 0 (nothing stored) when the stream runs out. */
#if defined(__GNUC__)
#define ALWAYS_INLINE inline __attribute__((always_inline))
#else
#define ALWAYS_INLINE inline
#endif

static ALWAYS_INLINE int job_step(mapped_job *j) {
    const uint16_t *slot_sym = j->slot_sym;
    const uint32_t *freqs = j->freqs, *cum = j->cum;
    const uint8_t *data = j->data;
    const Py_ssize_t end = j->end;
    uint32_t x = j->x;
    Py_ssize_t pos = j->pos;
    int ok = 0;
    do {
        DECODE_STEP(s)
        int code = j->centre ? (int)s + (int)j->centre[j->c] - j->top : (int)s;
        if (code < 0 || code > j->top) {
            j->bad = 1;
            code = 0;
        }
        j->out[j->i++] = j->lut[j->colbase[j->c] + (uint32_t)code];
        if (++j->c == j->cols) j->c = 0;
        ok = 1;
    } while (0);
    j->x = x;
    j->pos = pos;
    return ok;
}

/* The jobs tuple of decode_mapped / encode: 1 or 2 entries; -1 with an exception otherwise. */
static Py_ssize_t job_count(PyObject *args, PyObject **jobs, const char *name) {
    if (!PyArg_ParseTuple(args, "O!", &PyTuple_Type, jobs)) return -1;
    const Py_ssize_t n = PyTuple_GET_SIZE(*jobs);
    if (n < 1 || n > 2) {
        PyErr_Format(PyExc_ValueError, "%s takes 1 or 2 jobs", name);
        return -1;
    }
    return n;
}

/* Step jobs a and b (local copies, so their fields can live in registers) in turn while both have work
 * (MORE) and no step fails, then finish each alone. */
#define INTERLEAVE(a, b, n, MORE, STEP)                                   \
    do {                                                                  \
        int live0 = 1, live1 = (n) == 2;                                  \
        while (live0 && live1) {                                          \
            live0 = MORE(a) && STEP(&(a));                                \
            live1 = MORE(b) && STEP(&(b));                                \
        }                                                                 \
        while (live0 && MORE(a) && STEP(&(a))) {}                         \
        while (live1 && MORE(b) && STEP(&(b))) {}                         \
    } while (0)
#define DECODE_MORE(j) ((j).i < (j).count)
#define ENCODE_MORE(j) ((j).i > 0)

/* decode_mapped(jobs) -> [(symbols_decoded, stream_pos, final_state, bad), ...] for 1 or 2 jobs.  Two
 * independent streams (a scene's two token sections) are decoded in one loop, a symbol of each in turn:
 * each stream is a chain of dependent steps, and two chains keep the core busy ~1.4x as well as one. */
static PyObject *rans_decode_mapped(PyObject *self, PyObject *args) {
    PyObject *jobs, *result = NULL;
    const Py_ssize_t n = job_count(args, &jobs, "decode_mapped");
    if (n < 0) return NULL;
    mapped_job j[2];
    memset(j, 0, sizeof(j));
    int ready = 1;
    for (Py_ssize_t k = 0; k < n && ready; k++) ready = job_setup(&j[k], PyTuple_GET_ITEM(jobs, k));
    if (ready) {
        Py_BEGIN_ALLOW_THREADS
        mapped_job a = j[0], b = j[1];
        INTERLEAVE(a, b, n, DECODE_MORE, job_step);
        j[0].i = a.i, j[0].pos = a.pos, j[0].x = a.x, j[0].bad = a.bad;
        j[1].i = b.i, j[1].pos = b.pos, j[1].x = b.x, j[1].bad = b.bad;
        Py_END_ALLOW_THREADS
        result = PyList_New(n);
        for (Py_ssize_t k = 0; result && k < n; k++) {
            PyObject *item = Py_BuildValue("(nnki)", j[k].i, j[k].pos, (unsigned long)j[k].x, j[k].bad);
            if (!item) Py_CLEAR(result);
            else PyList_SET_ITEM(result, k, item);
        }
    }
    for (Py_ssize_t k = 0; k < n; k++) job_release(&j[k]);
    return result;
}

/* Encoder step constants of one symbol: x -> (x div f) * M + (x mod f) + cum as
 * x + bias + q * (M - f) with q = x div f from a reciprocal multiply (exact for every x < 2^31, which
 * holds as x < f << 17 <= 2^31 after renormalisation; checked for every f against x / f, and the tests
 * hold the output to the pure-Python encoder byte for byte).  f = 1 uses q = x - 1 with bias + M - 1. */
typedef struct {
    uint32_t x_max, rcp, shift, bias, cmpl;
} enc_symbol;

static void enc_symbol_init(enc_symbol *e, uint32_t f, uint32_t cum) {
    e->x_max = f << UPPER_SHIFT;
    e->cmpl = PROB_SCALE - f;
    if (f < 2) {
        e->rcp = 0xFFFFFFFFu;
        e->shift = 0;
        e->bias = cum + PROB_SCALE - 1;
    } else {
        uint32_t sh = 0;
        while (f > (1u << sh)) sh++;
        e->rcp = (uint32_t)(((1ull << (sh + 31)) + f - 1) / f);
        e->shift = sh - 1;
        e->bias = cum;
    }
}

/* One stream to encode: symbols, table, and the output being written backwards. */
typedef struct {
    Py_buffer yb, fb;
    int nbuf;
    uint32_t *cum;
    enc_symbol *tab;
    uint8_t *buf, *p;
    const uint16_t *sym;
    Py_ssize_t alphabet, i; /* i: symbols left to encode (encoding runs from the last to the first) */
    size_t cap;
    uint32_t x;
    int bad;
} enc_job;

static void enc_release(enc_job *j) {
    if (j->nbuf) {
        PyBuffer_Release(&j->yb);
        PyBuffer_Release(&j->fb);
        j->nbuf = 0;
    }
    PyMem_Free(j->cum);
    PyMem_Free(j->tab);
    PyMem_Free(j->buf);
    j->cum = NULL;
    j->tab = NULL;
    j->buf = NULL;
}

/* Parse (symbols_u16, freqs_u32) and prepare the tables and output; 0 on error. */
static int enc_setup(enc_job *j, PyObject *spec) {
    memset(j, 0, sizeof(*j));
    if (!PyTuple_Check(spec) || !PyArg_ParseTuple(spec, "y*y*", &j->yb, &j->fb)) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "encode: each job must be a tuple");
        return 0;
    }
    j->nbuf = 1;
    if (!table_arg(&j->fb, &j->alphabet)) return 0;
    if (j->yb.len % 2) {
        PyErr_SetString(PyExc_ValueError, "symbols must be a uint16 buffer");
        return 0;
    }
    const uint32_t *freqs = (const uint32_t *)j->fb.buf;
    j->cum = PyMem_Malloc(sizeof(uint32_t) * (size_t)j->alphabet);
    j->tab = PyMem_Malloc(sizeof(enc_symbol) * (size_t)j->alphabet);
    if (!j->cum || !j->tab) {
        PyErr_NoMemory();
        return 0;
    }
    if (!build_cum(freqs, j->alphabet, j->cum)) {
        PyErr_SetString(PyExc_ValueError, "frequency table does not sum to 2^14");
        return 0;
    }
    for (Py_ssize_t k = 0; k < j->alphabet; k++) enc_symbol_init(&j->tab[k], freqs[k], j->cum[k]);
    j->sym = (const uint16_t *)j->yb.buf;
    j->i = j->yb.len / 2;
    if (j->i > (PY_SSIZE_T_MAX - 4) / 2) {
        PyErr_NoMemory();
        return 0;
    }
    j->cap = 2 * (size_t)j->i + 4; /* each symbol emits at most 2 bytes, plus the final state */
    j->buf = PyMem_Malloc(j->cap);
    if (!j->buf) {
        PyErr_NoMemory();
        return 0;
    }
    j->p = j->buf + j->cap; /* bytes are written backwards, so the stream reads forwards */
    j->x = STATE_LOWER;
    return 1;
}

/* Encode symbol j->i - 1; 0 (and bad) if it has no frequency. */
static ALWAYS_INLINE int enc_step(enc_job *j) {
    uint16_t s = j->sym[j->i - 1];
    if (s >= j->alphabet || j->tab[s].x_max == 0) {
        j->bad = 1;
        return 0;
    }
    const enc_symbol *e = &j->tab[s];
    uint32_t x = j->x;
    uint8_t *p = j->p;
    while (x >= e->x_max) {
        *--p = (uint8_t)(x & 0xFF);
        x >>= 8;
    }
    uint32_t q = (uint32_t)(((uint64_t)x * e->rcp) >> 32) >> e->shift;
    j->x = x + e->bias + q * e->cmpl;
    j->p = p;
    j->i--;
    return 1;
}

/* encode(jobs) -> [stream bytes or None (a symbol without frequency), ...] for 1 or 2 (symbols_u16,
 * freqs_u32) jobs; two streams are encoded in one loop, a symbol of each in turn (as decode_mapped). */
static PyObject *rans_encode(PyObject *self, PyObject *args) {
    PyObject *jobs, *result = NULL;
    const Py_ssize_t n = job_count(args, &jobs, "encode");
    if (n < 0) return NULL;
    enc_job j[2];
    memset(j, 0, sizeof(j));
    int ready = 1;
    for (Py_ssize_t k = 0; k < n && ready; k++) ready = enc_setup(&j[k], PyTuple_GET_ITEM(jobs, k));
    if (ready) {
        Py_BEGIN_ALLOW_THREADS
        enc_job a = j[0], b = j[1];
        INTERLEAVE(a, b, n, ENCODE_MORE, enc_step);
        j[0].p = a.p, j[0].x = a.x, j[0].bad = a.bad;
        j[1].p = b.p, j[1].x = b.x, j[1].bad = b.bad;
        Py_END_ALLOW_THREADS
        result = PyList_New(n);
        for (Py_ssize_t k = 0; result && k < n; k++) {
            PyObject *item;
            if (j[k].bad) {
                item = Py_NewRef(Py_None);
            } else {
                uint8_t *p = j[k].p - 4;
                const uint32_t x = j[k].x;
                p[0] = (uint8_t)x;
                p[1] = (uint8_t)(x >> 8);
                p[2] = (uint8_t)(x >> 16);
                p[3] = (uint8_t)(x >> 24);
                item = PyBytes_FromStringAndSize((const char *)p, (Py_ssize_t)(j[k].buf + j[k].cap - p));
            }
            if (!item) Py_CLEAR(result);
            else PyList_SET_ITEM(result, k, item);
        }
    }
    for (Py_ssize_t k = 0; k < n; k++) enc_release(&j[k]);
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
     "decode_mapped(((stream, freqs_u32, out_f32, cols, colbase_u32, lut_f32, centre_u8_or_empty, top), ...))"
     " -> [(symbols_decoded, stream_pos, final_state, bad_code), ...] for 1 or 2 streams"},
    {"encode", rans_encode, METH_VARARGS,
     "encode(((symbols_u16, freqs_u32), ...)) -> [stream bytes, or None if a symbol has frequency 0, ...]"
     " for 1 or 2 streams"},
    {"column_histograms", column_histograms, METH_VARARGS,
     "column_histograms(codes_u8, cols, size, out_i64): count code v of column c into out[c * size + v]"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_rans_native",
                                    "The rANS coder of FORMAT.md I.6.1 in C (see rans.py).", -1, methods};

PyMODINIT_FUNC PyInit__rans_native(void) { return PyModule_Create(&module); }
