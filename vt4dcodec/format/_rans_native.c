/* The static rANS coder of FORMAT.md I.6.1 in C: the same stream bytes as the pure-Python reference in
 * rans.py, about 1,000x faster.  Integer arithmetic only (uint32 states; uint64 only to shift a state and the
 * next two stream bytes as one value), so every
 * machine produces and accepts the same bytes.
 *
 * A stream has K = 1..32 interleaved lanes (format 1.5, required flag bit 4; K = 1 is the single chain of
 * 1.1-1.4): K initial u32 states, lane 0 first, then one shared run of renormalisation bytes; symbol k is
 * decoded by lane k mod K.  Lanes are independent chains of dependent steps, so a core runs K of them at
 * once where one chain leaves it waiting on each step's table look-ups and multiply.
 *
 * Both functions take frequency tables that rans.py has already validated (parse_table / normalize_counts);
 * they re-check the sum and every symbol index anyway, so no input can make them read or write out of
 * bounds.  Work is bounded by the declared symbol count: each decoded symbol reads at most 2 stream bytes
 * and each encoded symbol writes at most 2.  The GIL is released while coding.
 *
 *   decode(stream, freqs_u32, out_u16[, lanes]) -> (symbols_decoded, stream_pos, final_states)
 *   decode_mapped(...): decode, symbols -> codes -> float32 by table in the same pass (see below)
 *   encode(jobs) -> [bytes, or None if a symbol has frequency 0 or lies outside the table] for 1-2 streams
 *   column_histograms(codes_u8, cols, size, out_i64) -> None: out[(k % cols) * size + codes[k]] += 1, or
 *       ValueError if a code is >= size (the writer's one counting pass, for its median and both tables)
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

#define PROB_BITS 14
#define PROB_SCALE (1u << PROB_BITS)
#define STATE_LOWER (1u << 23)
#define UPPER_SHIFT (23 - PROB_BITS + 8) /* x_max(s) = f[s] << 17 */
#define MAX_ALPHABET 65536
#define MAX_LANES 32

#if defined(__GNUC__)
#define ALWAYS_INLINE inline __attribute__((always_inline))
#else
#define ALWAYS_INLINE inline
#endif

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

static int lanes_arg(int lanes) {
    if (lanes < 1 || lanes > MAX_LANES) {
        PyErr_SetString(PyExc_ValueError, "lanes must be 1..32");
        return 0;
    }
    return 1;
}

/* Decoder tables: cum[] and the slot -> symbol map (caller frees both with PyMem_Free). */
static int decoder_tables(Py_buffer *fb, Py_buffer *sb, int lanes, uint32_t **cum, uint16_t **slot_sym) {
    Py_ssize_t alphabet;
    *cum = NULL;
    *slot_sym = NULL;
    if (!table_arg(fb, &alphabet) || !lanes_arg(lanes)) return 0;
    if (sb->len < 4 * (Py_ssize_t)lanes) {
        PyErr_SetString(PyExc_ValueError, "stream shorter than its initial states");
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

static uint32_t read_u32(const uint8_t *data) {
    return (uint32_t)data[0] | (uint32_t)data[1] << 8 | (uint32_t)data[2] << 16 | (uint32_t)data[3] << 24;
}

/* The final states as a tuple of ints, lane 0 first. */
static PyObject *states_tuple(const uint32_t *x, int lanes) {
    PyObject *t = PyTuple_New(lanes);
    for (int l = 0; t && l < lanes; l++) {
        PyObject *v = PyLong_FromUnsignedLong((unsigned long)x[l]);
        if (!v) Py_CLEAR(t);
        else PyTuple_SET_ITEM(t, l, v);
    }
    return t;
}

/* One decoding step of FORMAT.md I.6.1 on state x: symbol s, then renormalise from data[pos..end);
 * `break`s out of the caller's loop (before storing symbol i) when the stream runs out. */
#define DECODE_STEP(x, s)                                               \
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
    int lanes = 1;
    if (!PyArg_ParseTuple(args, "y*y*w*|i", &sb, &fb, &ob, &lanes)) return NULL;
    PyObject *result = NULL;
    uint32_t *cum = NULL;
    uint16_t *slot_sym = NULL;
    if (!decoder_tables(&fb, &sb, lanes, &cum, &slot_sym)) goto done;
    if (ob.len % 2) {
        PyErr_SetString(PyExc_ValueError, "out must be a uint16 buffer");
        goto done;
    }
    const uint32_t *freqs = (const uint32_t *)fb.buf;
    const uint8_t *data = (const uint8_t *)sb.buf;
    const Py_ssize_t end = sb.len, count = ob.len / 2;
    uint16_t *out = (uint16_t *)ob.buf;
    uint32_t states[MAX_LANES];
    for (int l = 0; l < lanes; l++) states[l] = read_u32(data + 4 * l);
    Py_ssize_t pos = 4 * (Py_ssize_t)lanes, i = 0;
    Py_BEGIN_ALLOW_THREADS
    if (lanes == 1) {
        uint32_t x = states[0];
        for (; i < count; i++) {
            DECODE_STEP(x, s)
            out[i] = s;
        }
        states[0] = x;
    } else {
        int lane = 0;
        for (; i < count; i++) {
            uint32_t x = states[lane];
            DECODE_STEP(x, s)
            out[i] = s;
            states[lane] = x;
            if (++lane == lanes) lane = 0;
        }
    }
    Py_END_ALLOW_THREADS
    PyObject *st = states_tuple(states, lanes);
    if (st) result = Py_BuildValue("(nnN)", i, pos, st);
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
    uint8_t *slot_sym8; /* the same map in bytes, where the alphabet has at most 256 symbols (else NULL) */
    const uint32_t *freqs, *colbase;
    const float *lut;
    const uint8_t *centre, *data;
    float *out;
    Py_ssize_t end, pos, count, i, cols, c;
    int top, bad, lanes, lane; /* lane: the lane of symbol i */
    int checked; /* whether codes need the range check (centre given, or symbols beyond top) */
    uint32_t x[MAX_LANES];
} mapped_job;

static void job_release(mapped_job *j) {
    Py_buffer *bufs[6] = {&j->sb, &j->fb, &j->ob, &j->cb, &j->lb, &j->zb};
    for (int k = 0; k < j->nbuf; k++) PyBuffer_Release(bufs[k]);
    j->nbuf = 0;
    PyMem_Free(j->cum);
    PyMem_Free(j->slot_sym);
    PyMem_Free(j->slot_sym8);
    j->cum = NULL;
    j->slot_sym = NULL;
    j->slot_sym8 = NULL;
}

/* Parse (stream, freqs_u32, out_f32, cols, colbase_u32, lut_f32, centre_u8_or_empty, top[, lanes]); 0 on
 * error. */
static int job_setup(mapped_job *j, PyObject *spec) {
    memset(j, 0, sizeof(*j));
    j->lanes = 1;
    if (!PyTuple_Check(spec) || !PyArg_ParseTuple(spec, "y*y*w*ny*y*y*i|i", &j->sb, &j->fb, &j->ob, &j->cols, &j->cb,
                                                  &j->lb, &j->zb, &j->top, &j->lanes)) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "decode_mapped: each job must be a tuple");
        return 0;
    }
    j->nbuf = 6;
    if (!decoder_tables(&j->fb, &j->sb, j->lanes, &j->cum, &j->slot_sym)) return 0;
    const Py_ssize_t lut_len = j->lb.len / 4, alphabet = j->fb.len / 4;
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
    if (alphabet <= 256 && j->lanes > 1) { /* for job_lanes */
        j->slot_sym8 = PyMem_Malloc(PROB_SCALE);
        if (!j->slot_sym8) {
            PyErr_NoMemory();
            return 0;
        }
        for (Py_ssize_t s = 0; s < alphabet; s++) memset(j->slot_sym8 + j->cum[s], (int)s, j->freqs[s]);
    }
    j->lut = (const float *)j->lb.buf;
    j->centre = j->zb.len ? (const uint8_t *)j->zb.buf : NULL;
    j->checked = j->centre != NULL || alphabet > j->top + 1;
    j->data = (const uint8_t *)j->sb.buf;
    j->end = j->sb.len;
    j->count = j->ob.len / 4;
    j->out = (float *)j->ob.buf;
    for (int l = 0; l < j->lanes; l++) j->x[l] = read_u32(j->data + 4 * l);
    j->pos = 4 * (Py_ssize_t)j->lanes;
    return 1;
}

/* Map decoded symbol s of column c to its float and store it as out[i]. */
#define MAP_STORE(j, s, i, c)                                                       \
    do {                                                                            \
        int code_ = (j)->centre ? (int)(s) + (int)(j)->centre[c] - (j)->top : (int)(s); \
        if (code_ < 0 || code_ > (j)->top) {                                        \
            (j)->bad = 1;                                                           \
            code_ = 0;                                                              \
        }                                                                           \
        (j)->out[i] = (j)->lut[(j)->colbase[c] + (uint32_t)code_];                  \
    } while (0)

/* Decode and store symbol j->i with its lane's state (LANES: whether there may be more than one lane); 0
 * (nothing stored) when the stream runs out. */
static ALWAYS_INLINE int job_step_any(mapped_job *j, const int LANES) {
    const uint16_t *slot_sym = j->slot_sym;
    const uint32_t *freqs = j->freqs, *cum = j->cum;
    const uint8_t *data = j->data;
    const Py_ssize_t end = j->end;
    uint32_t x = j->x[LANES ? j->lane : 0];
    Py_ssize_t pos = j->pos;
    int ok = 0;
    do {
        DECODE_STEP(x, s)
        MAP_STORE(j, s, j->i, j->c);
        j->i++;
        if (++j->c == j->cols) j->c = 0;
        ok = 1;
    } while (0);
    if (LANES) {
        j->x[j->lane] = x;
        if (++j->lane == j->lanes) j->lane = 0;
    } else {
        j->x[0] = x;
    }
    j->pos = pos;
    return ok;
}
#define job_step(j) job_step_any(j, 1)
#define job_step1(j) job_step_any(j, 0)

/* The lane path (K >= 2): job j's symbols a round at a time, one symbol of each lane (lane l: symbol
 * i + l), while a round cannot run out of stream (K symbols read at most 2 K bytes), with the step of
 * DECODE_STEP made branch-free: after a step x >= 2^9 (x >= L before it, so x div M >= 2^9, and f >= 1),
 * so the checked loop reads exactly n = [x < L] + [x < L / 256] bytes (x * 256 + byte < L exactly when
 * x < 2^15); x then takes the next n of the next 2 bytes: (x * 2^16 + next 2 bytes) >> (16 - 8 n).
 * Everything hot is a local, the K states too (K is a constant in each copy the compiler makes), and
 * symbols come from the byte-wide slot map where the alphabet allows (half the cache).  What is left
 * (fewer than K symbols, or the last 2 K bytes of the stream) is job_step's. */
#define LANE_SYMBOL(slot) (SYM8 ? (uint32_t)slot_sym8[slot] : (uint32_t)slot_sym[slot])
#define LANE_DECODE(l)                                                                      \
    uint32_t xl = x[l];                                                                     \
    const uint32_t slot = xl & (PROB_SCALE - 1);                                            \
    const uint32_t s = LANE_SYMBOL(slot);                                                   \
    xl = freqs[s] * (xl >> PROB_BITS) + slot - cum[s];                                      \
    {                                                                                       \
        const uint32_t nb = (xl < STATE_LOWER) + (xl < (STATE_LOWER >> 8));                 \
        const uint64_t v = (uint64_t)xl << 16 | (uint32_t)data[pos] << 8 | data[pos + 1];   \
        x[l] = (uint32_t)(v >> (16 - 8 * nb));                                              \
        pos += nb;                                                                          \
    }

/* Whole rows (cols a multiple of K, c = 0 at the start): the column is the loop index, one check a row. */
static ALWAYS_INLINE void job_rows(mapped_job *j, const int K, const int SYM8, const int CENTRE) {
    const uint16_t *slot_sym = j->slot_sym;
    const uint8_t *slot_sym8 = j->slot_sym8;
    const uint32_t *freqs = j->freqs, *cum = j->cum, *colbase = j->colbase;
    const uint8_t *data = j->data, *centre = j->centre;
    const float *lut = j->lut;
    float *out = j->out;
    const Py_ssize_t cols = j->cols, count = j->count, end = j->end;
    const unsigned top = (unsigned)j->top;
    Py_ssize_t pos = j->pos, i = j->i;
    unsigned bad = 0;
    uint32_t x[8];
    for (int l = 0; l < K; l++) x[l] = j->x[l];
    while (count - i >= cols && end - pos >= 2 * cols) {
        float *row = out + i;
        for (Py_ssize_t c0 = 0; c0 < cols; c0 += K) {
#pragma GCC unroll 8
            for (int l = 0; l < K; l++) {
                LANE_DECODE(l)
                unsigned code = s;
                if (CENTRE) {
                    code = s + centre[c0 + l] - top;
                    const unsigned out_of_range = code > top;
                    bad |= out_of_range;
                    code = out_of_range ? 0 : code;
                }
                row[c0 + l] = lut[colbase[c0 + l] + code];
            }
        }
        i += cols;
    }
    for (int l = 0; l < K; l++) j->x[l] = x[l];
    j->pos = pos;
    j->i = i;
    j->bad |= (int)bad;
}

/* Rounds of K symbols from any column (cols not a multiple of K, or a file of few rows). */
static void job_rounds(mapped_job *j) {
    const int K = j->lanes, SYM8 = j->slot_sym8 != NULL;
    const uint16_t *slot_sym = j->slot_sym;
    const uint8_t *slot_sym8 = j->slot_sym8;
    const uint32_t *freqs = j->freqs, *cum = j->cum;
    const uint8_t *data = j->data;
    const Py_ssize_t count = j->count, end = j->end;
    Py_ssize_t pos = j->pos;
    uint32_t x[MAX_LANES];
    for (int l = 0; l < K; l++) x[l] = j->x[l];
    while (count - j->i >= K && end - pos >= 2 * (Py_ssize_t)K) {
        for (int l = 0; l < K; l++) {
            LANE_DECODE(l)
            MAP_STORE(j, s, j->i, j->c);
            j->i++;
            if (++j->c == j->cols) j->c = 0;
        }
    }
    for (int l = 0; l < K; l++) j->x[l] = x[l];
    j->pos = pos;
}

/* The rows of job j (where they apply), then its rounds; job_step finishes it. */
static void job_lanes(mapped_job *j) {
    if (j->checked && !j->centre) return; /* symbols beyond top without prediction: only job_step checks them */
    if (j->c == 0 && j->lane == 0 && j->cols % j->lanes == 0 && (j->lanes == 4 || j->lanes == 8)) {
        const int sym8 = j->slot_sym8 != NULL, centre = j->centre != NULL;
#define ROWS(K) (sym8 ? (centre ? job_rows(j, K, 1, 1) : job_rows(j, K, 1, 0)) \
                      : (centre ? job_rows(j, K, 0, 1) : job_rows(j, K, 0, 0)))
        if (j->lanes == 4) ROWS(4);
        else ROWS(8);
#undef ROWS
        j->c = j->i % j->cols;
    }
    if (j->lane == 0) job_rounds(j);
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

/* The symbol-by-symbol steps of jobs a and b in turn (local copies, so their fields can live in
 * registers): the whole decode of single chains, the last symbols of lanes. */
static void steps_single(mapped_job *pa, mapped_job *pb, Py_ssize_t n) {
    mapped_job a = *pa, b = *pb;
    INTERLEAVE(a, b, n, DECODE_MORE, job_step1);
    *pa = a;
    *pb = b;
}

static void steps_lanes(mapped_job *pa, mapped_job *pb, Py_ssize_t n) {
    mapped_job a = *pa, b = *pb;
    INTERLEAVE(a, b, n, DECODE_MORE, job_step);
    *pa = a;
    *pb = b;
}

/* decode_mapped(jobs) -> [(symbols_decoded, stream_pos, final_states, bad), ...] for 1 or 2 jobs.  A
 * stream of K >= 2 lanes keeps the core busy on its own (job_lanes); single chains (K = 1, the 1.1-1.4
 * layout) of a scene's two token sections are decoded in one loop, a symbol of each in turn: two chains
 * keep the core busy ~1.4x as well as one.  Every stream ends symbol by symbol (job_step), which also
 * catches truncation exactly as the Python reference does. */
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
        for (Py_ssize_t k = 0; k < n; k++)
            if (j[k].lanes > 1) job_lanes(&j[k]);
        if (j[0].lanes == 1 && j[1].lanes <= 1) /* (j[1].lanes is 0 where there is no second job) */
            steps_single(&j[0], &j[1], n);
        else
            steps_lanes(&j[0], &j[1], n);
        Py_END_ALLOW_THREADS
        result = PyList_New(n);
        for (Py_ssize_t k = 0; result && k < n; k++) {
            PyObject *st = states_tuple(j[k].x, j[k].lanes);
            PyObject *item = st ? Py_BuildValue("(nnNi)", j[k].i, j[k].pos, st, j[k].bad) : NULL;
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
    int bad, lanes, lane; /* lane: the lane of symbol i - 1, the next to encode */
    uint32_t x[MAX_LANES];
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

/* Parse (symbols_u16, freqs_u32[, lanes]) and prepare the tables and output; 0 on error. */
static int enc_setup(enc_job *j, PyObject *spec) {
    memset(j, 0, sizeof(*j));
    j->lanes = 1;
    if (!PyTuple_Check(spec) || !PyArg_ParseTuple(spec, "y*y*|i", &j->yb, &j->fb, &j->lanes)) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_TypeError, "encode: each job must be a tuple");
        return 0;
    }
    j->nbuf = 1;
    if (!table_arg(&j->fb, &j->alphabet) || !lanes_arg(j->lanes)) return 0;
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
    if (j->i > (PY_SSIZE_T_MAX - 4 * MAX_LANES) / 2) {
        PyErr_NoMemory();
        return 0;
    }
    j->cap = 2 * (size_t)j->i + 4 * (size_t)j->lanes; /* each symbol emits at most 2 bytes, plus the states */
    j->buf = PyMem_Malloc(j->cap);
    if (!j->buf) {
        PyErr_NoMemory();
        return 0;
    }
    j->p = j->buf + j->cap; /* bytes are written backwards, so the stream reads forwards */
    for (int l = 0; l < j->lanes; l++) j->x[l] = STATE_LOWER;
    j->lane = j->i ? (int)((j->i - 1) % j->lanes) : 0;
    return 1;
}

/* Encode symbol j->i - 1 with its lane's state; 0 (and bad) if it has no frequency. */
static ALWAYS_INLINE int enc_step(enc_job *j) {
    uint16_t s = j->sym[j->i - 1];
    if (s >= j->alphabet || j->tab[s].x_max == 0) {
        j->bad = 1;
        return 0;
    }
    const enc_symbol *e = &j->tab[s];
    uint32_t x = j->x[j->lane];
    uint8_t *p = j->p;
    while (x >= e->x_max) {
        *--p = (uint8_t)(x & 0xFF);
        x >>= 8;
    }
    uint32_t q = (uint32_t)(((uint64_t)x * e->rcp) >> 32) >> e->shift;
    j->x[j->lane] = x + e->bias + q * e->cmpl;
    j->lane = j->lane ? j->lane - 1 : j->lanes - 1;
    j->p = p;
    j->i--;
    return 1;
}

/* The lane path of the encoder (K >= 2, the symbols left a multiple of K, so symbol i - 1 is lane K - 1's):
 * rounds of K symbols, lanes K - 1 down to 0, the states in locals (K a constant in each copy the compiler
 * makes).  Stops at a symbol without frequency (bad); the caller finishes with enc_step. */
static ALWAYS_INLINE void enc_rounds(enc_job *j, const int K) {
    const enc_symbol *tab = j->tab;
    const uint16_t *sym = j->sym;
    const Py_ssize_t alphabet = j->alphabet;
    uint8_t *p = j->p;
    Py_ssize_t i = j->i;
    uint32_t x[MAX_LANES];
    for (int l = 0; l < K; l++) x[l] = j->x[l];
    while (i >= K) {
        for (int l = K - 1; l >= 0; l--) {
            const uint16_t s = sym[i - K + l];
            if (s >= alphabet || tab[s].x_max == 0) {
                j->bad = 1;
                j->i = 0; /* nothing more to encode: the result is None */
                return;
            }
            const enc_symbol *e = &tab[s];
            uint32_t xl = x[l];
            /* the while loop of enc_step without branches: it emits nb <= 2 bytes (x < 2^32 <= x_max * 2^15),
             * the low one first; both are written, p moves by nb (a byte written below the new p is overwritten
             * later, by the next bytes or the final states, and p - 2 >= buf as 2 bytes a symbol are reserved) */
            const uint32_t nb = (xl >= e->x_max) + ((xl >> 8) >= e->x_max);
            p[-1] = (uint8_t)xl;
            p[-2] = (uint8_t)(xl >> 8);
            p -= nb;
            xl = (uint32_t)((uint64_t)xl >> (8 * nb));
            const uint32_t q = (uint32_t)(((uint64_t)xl * e->rcp) >> 32) >> e->shift;
            x[l] = xl + e->bias + q * e->cmpl;
        }
        i -= K;
    }
    for (int l = 0; l < K; l++) j->x[l] = x[l];
    j->p = p;
    j->i = i;
}

static void enc_lanes(enc_job *j) {
    while (j->i % j->lanes && enc_step(j)) {} /* the last n mod K symbols first */
    if (j->bad) {
        j->i = 0;
        return;
    }
    switch (j->lanes) {
    case 2: enc_rounds(j, 2); break;
    case 4: enc_rounds(j, 4); break;
    case 8: enc_rounds(j, 8); break;
    default: enc_rounds(j, j->lanes); break;
    }
}

/* encode(jobs) -> [stream bytes or None (a symbol without frequency), ...] for 1 or 2 (symbols_u16,
 * freqs_u32[, lanes]) jobs; two streams are encoded in one loop, a symbol of each in turn.  A stream is
 * the K final states (lane 0 first) and then the emitted bytes in reverse order of emission. */
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
        for (Py_ssize_t k = 0; k < n; k++) /* lanes keep the core busy on their own; single chains in turn */
            if (j[k].lanes > 1) enc_lanes(&j[k]);
        enc_job a = j[0], b = j[1];
        INTERLEAVE(a, b, n, ENCODE_MORE, enc_step);
        j[0] = a;
        j[1] = b;
        Py_END_ALLOW_THREADS
        result = PyList_New(n);
        for (Py_ssize_t k = 0; result && k < n; k++) {
            PyObject *item;
            if (j[k].bad) {
                item = Py_NewRef(Py_None);
            } else {
                uint8_t *p = j[k].p - 4 * j[k].lanes;
                for (int l = 0; l < j[k].lanes; l++) {
                    const uint32_t x = j[k].x[l];
                    p[4 * l] = (uint8_t)x;
                    p[4 * l + 1] = (uint8_t)(x >> 8);
                    p[4 * l + 2] = (uint8_t)(x >> 16);
                    p[4 * l + 3] = (uint8_t)(x >> 24);
                }
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

/* Binary64 arithmetic exactly as written, one IEEE 754 rounding per operation: the build passes
 * -ffp-contract=off (no fused multiply-add), and a target that evaluates in wider precision (x87,
 * FLT_EVAL_METHOD != 0) gets no compiled float paths at all (the functions below return None and the callers
 * use numpy). */
#if defined(FLT_EVAL_METHOD) && FLT_EVAL_METHOD == 0
#define EXACT_BINARY64 1
#else
#define EXACT_BINARY64 0
#endif

/* quaternions_to_rotations(q_f64, out_f64) -> True: the rotations of n quaternions (w, x, y, z) (4 n values
 * in, 9 n out, row-major 3 x 3), FORMAT.md I.5.2's formula operation for operation; None where the target
 * cannot compute binary64 exactly (EXACT_BINARY64). */
static PyObject *quaternions_to_rotations(PyObject *self, PyObject *args) {
    Py_buffer qb, ob;
    if (!PyArg_ParseTuple(args, "y*w*", &qb, &ob)) return NULL;
    PyObject *result = NULL;
    const Py_ssize_t n = qb.len / (Py_ssize_t)(4 * sizeof(double));
    if (qb.len % (Py_ssize_t)(4 * sizeof(double)) || ob.len != n * (Py_ssize_t)(9 * sizeof(double))) {
        PyErr_SetString(PyExc_ValueError, "quaternions_to_rotations: shapes do not match");
        goto done;
    }
    if (!EXACT_BINARY64) {
        result = Py_NewRef(Py_None);
        goto done;
    }
    const double *q = (const double *)qb.buf;
    double *R = (double *)ob.buf;
    for (Py_ssize_t i = 0; i < n; i++, q += 4, R += 9) {
        const double w = q[0], x = q[1], y = q[2], z = q[3];
        const double s = 2.0 / (((w * w + x * x) + y * y) + z * z);
        R[0] = 1.0 - s * (y * y + z * z);
        R[1] = s * (x * y - w * z);
        R[2] = s * (x * z + w * y);
        R[3] = s * (x * y + w * z);
        R[4] = 1.0 - s * (x * x + z * z);
        R[5] = s * (y * z - w * x);
        R[6] = s * (x * z - w * y);
        R[7] = s * (y * z + w * x);
        R[8] = 1.0 - s * (x * x + y * y);
    }
    result = Py_NewRef(Py_True);
done:
    PyBuffer_Release(&qb);
    PyBuffer_Release(&ob);
    return result;
}

/* rotations_to_quaternions(R_f64, continuous, out_f64) -> True: compact_cameras.rotation_to_quaternion in C,
 * the same binary64 operations in the same order (Shepperd's method from the first largest of the trace, R00,
 * R11, R22; normalised by the square root of ((w^2 + x^2) + y^2) + z^2; signs against (1, 0, 0, 0), or with
 * ``continuous`` following the previous record).  None where an input value is not finite or binary64 is not
 * exact (EXACT_BINARY64): the caller's numpy path then computes. */
static PyObject *rotations_to_quaternions(PyObject *self, PyObject *args) {
    Py_buffer rb, ob;
    int continuous;
    if (!PyArg_ParseTuple(args, "y*pw*", &rb, &continuous, &ob)) return NULL;
    PyObject *result = NULL;
    const Py_ssize_t n = rb.len / (Py_ssize_t)(9 * sizeof(double));
    if (rb.len % (Py_ssize_t)(9 * sizeof(double)) || ob.len != n * (Py_ssize_t)(4 * sizeof(double))) {
        PyErr_SetString(PyExc_ValueError, "rotations_to_quaternions: shapes do not match");
        goto done;
    }
    if (!EXACT_BINARY64) {
        result = Py_NewRef(Py_None);
        goto done;
    }
    const double *m = (const double *)rb.buf;
    for (Py_ssize_t i = 0; i < 9 * n; i++) {
        if (!(m[i] - m[i] == 0.0)) {  /* inf - inf and NaN - NaN are NaN */
            result = Py_NewRef(Py_None);
            goto done;
        }
    }
    double *out = (double *)ob.buf;
    int prev_flip = 0;
    double prev[4] = {0.0, 0.0, 0.0, 0.0};  /* the previous record before its sign was chosen */
    for (Py_ssize_t i = 0; i < n; i++, m += 9) {
        const double m00 = m[0], m01 = m[1], m02 = m[2], m10 = m[3], m11 = m[4], m12 = m[5];
        const double m20 = m[6], m21 = m[7], m22 = m[8];
        const double trace = (m00 + m11) + m22;
        int k = 0;
        double best = trace;
        if (m00 > best) { k = 1; best = m00; }
        if (m11 > best) { k = 2; best = m11; }
        if (m22 > best) { k = 3; }
        double q[4];
        if (k == 0) {
            const double a = 1.0 + trace, w = 0.5 * sqrt(a > 0.0 ? a : 0.0), d = 4 * w;
            q[0] = w; q[1] = (m21 - m12) / d; q[2] = (m02 - m20) / d; q[3] = (m10 - m01) / d;
        } else if (k == 1) {
            const double a = ((1.0 + m00) - m11) - m22, x = 0.5 * sqrt(a > 0.0 ? a : 0.0), d = 4 * x;
            q[0] = (m21 - m12) / d; q[1] = x; q[2] = (m01 + m10) / d; q[3] = (m02 + m20) / d;
        } else if (k == 2) {
            const double a = ((1.0 - m00) + m11) - m22, y = 0.5 * sqrt(a > 0.0 ? a : 0.0), d = 4 * y;
            q[0] = (m02 - m20) / d; q[1] = (m01 + m10) / d; q[2] = y; q[3] = (m12 + m21) / d;
        } else {
            const double a = ((1.0 - m00) - m11) + m22, z = 0.5 * sqrt(a > 0.0 ? a : 0.0), d = 4 * z;
            q[0] = (m10 - m01) / d; q[1] = (m02 + m20) / d; q[2] = (m12 + m21) / d; q[3] = z;
        }
        const double norm = sqrt(((q[0] * q[0] + q[1] * q[1]) + q[2] * q[2]) + q[3] * q[3]);
        double v[4];
        for (int j = 0; j < 4; j++) v[j] = q[j] / norm;
        int flip = v[0] < 0;
        if (continuous && i > 0) {
            const double dot = ((v[0] * prev[0] + v[1] * prev[1]) + v[2] * prev[2]) + v[3] * prev[3];
            flip = (prev_flip ? -dot : dot) < 0;
        }
        for (int j = 0; j < 4; j++) {
            out[4 * i + j] = flip ? -v[j] : v[j];
            prev[j] = v[j];
        }
        prev_flip = flip;
    }
    result = Py_NewRef(Py_True);
done:
    PyBuffer_Release(&rb);
    PyBuffer_Release(&ob);
    return result;
}

/* cameras_valid(K_f64, w2c_f64, timestamps_f64) -> bool: whether n decoded cameras (9 n intrinsics, 16 n pose
 * values, 0 or n timestamps) plainly satisfy the camera conventions (vt4dcodec.cameras): finite values, fx and
 * fy > 0, K's last row (0, 0, 1) and K[1, 0] = 0, a pose's last row (0, 0, 0, 1), a rotation orthonormal to
 * half the tolerance (max |R^T R - I| <= 5e-5) with a positive determinant, non-decreasing timestamps.  True
 * only lets the caller skip the checks that would pass; False says nothing (the caller's checks then decide
 * and name the problem), so near the tolerance the numpy checks are the ones that decide. */
static PyObject *cameras_valid(PyObject *self, PyObject *args) {
    Py_buffer kb, wb, tb;
    if (!PyArg_ParseTuple(args, "y*y*y*", &kb, &wb, &tb)) return NULL;
    PyObject *result = NULL;
    const Py_ssize_t n = kb.len / (Py_ssize_t)(9 * sizeof(double));
    if (kb.len % (Py_ssize_t)(9 * sizeof(double)) || wb.len != n * (Py_ssize_t)(16 * sizeof(double))
        || (tb.len != 0 && tb.len != n * (Py_ssize_t)sizeof(double))) {
        PyErr_SetString(PyExc_ValueError, "cameras_valid: shapes do not match");
        goto done;
    }
    int ok = 1;
    const double *K = (const double *)kb.buf, *P = (const double *)wb.buf, *ts = (const double *)tb.buf;
    for (Py_ssize_t i = 0; i < n && ok; i++, K += 9, P += 16) {
        for (int j = 0; j < 9; j++) if (!(K[j] - K[j] == 0.0)) ok = 0;
        for (int j = 0; j < 16; j++) if (!(P[j] - P[j] == 0.0)) ok = 0;
        if (!ok || !(K[0] > 0.0 && K[4] > 0.0) || K[3] != 0.0 || K[6] != 0.0 || K[7] != 0.0 || K[8] != 1.0
            || P[12] != 0.0 || P[13] != 0.0 || P[14] != 0.0 || P[15] != 1.0) {
            ok = 0;
            break;
        }
        const double r[9] = {P[0], P[1], P[2], P[4], P[5], P[6], P[8], P[9], P[10]};
        for (int a = 0; a < 3 && ok; a++) {
            for (int b = 0; b < 3; b++) {
                const double g = (r[a] * r[b] + r[3 + a] * r[3 + b]) + r[6 + a] * r[6 + b];
                if (!(fabs(g - (a == b ? 1.0 : 0.0)) <= 5e-5)) { ok = 0; break; }
            }
        }
        const double det = r[0] * (r[4] * r[8] - r[5] * r[7]) - r[1] * (r[3] * r[8] - r[5] * r[6])
                           + r[2] * (r[3] * r[7] - r[4] * r[6]);
        if (!(det > 0.0)) ok = 0;
        if (tb.len && !(ts[i] - ts[i] == 0.0 && (i == 0 || ts[i] >= ts[i - 1]))) ok = 0;
    }
    result = PyBool_FromLong(ok);
done:
    PyBuffer_Release(&kb);
    PyBuffer_Release(&wb);
    PyBuffer_Release(&tb);
    return result;
}

/* dequantize_u8(codes_u8, cols, scale_f32, offset_f32, out_f32) -> bool: out[r, c] = f32(f64(offset[c]) +
 * f64(scale[c]) * codes[r, c]) (the affine decoding formula, FORMAT.md "Affine encodings"): one multiply and
 * one add in binary64, each rounded (built with -ffp-contract=off: never fused), then rounded to binary32.
 * With scale >= 0 every column's values are non-decreasing in the code (rounding is monotone), so when its
 * values at codes 0 and 255 lie within float32's finite range all of them do.  False, with nothing written,
 * when some column's do not (or a scale is negative or NaN), or where binary64 is not exact (EXACT_BINARY64):
 * the caller's checked path then decodes. */
static PyObject *dequantize_u8(PyObject *self, PyObject *args) {
    Py_buffer cb, sb, obuf, ob;
    Py_ssize_t cols;
    if (!PyArg_ParseTuple(args, "y*ny*y*w*", &cb, &cols, &sb, &obuf, &ob)) return NULL;
    PyObject *result = NULL;
    double *so = NULL;
    if (cols < 1 || cb.len % cols || sb.len != (Py_ssize_t)sizeof(float) * cols
        || obuf.len != (Py_ssize_t)sizeof(float) * cols || ob.len != (Py_ssize_t)sizeof(float) * cb.len) {
        PyErr_SetString(PyExc_ValueError, "dequantize_u8: shapes do not match");
        goto done;
    }
    if (!EXACT_BINARY64) {
        result = Py_NewRef(Py_False);
        goto done;
    }
    so = PyMem_Malloc(sizeof(double) * 2 * (size_t)cols);
    if (!so) {
        PyErr_NoMemory();
        goto done;
    }
    const float *scale = (const float *)sb.buf, *offset = (const float *)obuf.buf;
    double *s = so, *o = so + cols;
    int finite = 1;
    for (Py_ssize_t c = 0; c < cols; c++) {
        s[c] = (double)scale[c];
        o[c] = (double)offset[c];
        const double top = o[c] + s[c] * 255.0;
        /* NaN fails every comparison; a value beyond FLT_MAX (even one a float32 cast would round down to it)
         * goes to the caller's path, so every conversion below is of a value within float32's range */
        if (!(s[c] >= 0.0 && o[c] >= -(double)FLT_MAX && top <= (double)FLT_MAX)) finite = 0;
    }
    if (finite) {
        const uint8_t *codes = (const uint8_t *)cb.buf;
        float *out = (float *)ob.buf;
        const Py_ssize_t rows = cb.len / cols;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t r = 0; r < rows; r++) {
            const uint8_t *row = codes + r * cols;
            float *dst = out + r * cols;
            for (Py_ssize_t c = 0; c < cols; c++) dst[c] = (float)(o[c] + s[c] * (double)row[c]);
        }
        Py_END_ALLOW_THREADS
    }
    result = PyBool_FromLong(finite);
done:
    PyMem_Free(so);
    PyBuffer_Release(&cb);
    PyBuffer_Release(&sb);
    PyBuffer_Release(&obuf);
    PyBuffer_Release(&ob);
    return result;
}

/* Context-coded streams (format 1.6, learned-rans): one chain, symbol k coded with frequency table ctx[k]
 * of T tables of A symbols each (freqs_u32 holds T * A values, table t at t * A).  Every table must sum
 * to PROB_SCALE (checked here again); a symbol of frequency 0 cannot be encoded.
 *   encode_ctx(symbols_u16, ctx_u16, freqs_u32, A, adaptive) -> bytes, or None if a symbol has frequency 0 or
 *       lies outside its table (with adaptive, outside its row's symbol count)
 *   decode_ctx(stream, ctx_u16, freqs_u32, A, adaptive, out_u16[, dep_i32, centre_u16, dep2_i32, centre2_u16,
 *       offsets_i32])
 *       -> (symbols_decoded, stream_pos, final_state); with the dependency buffers (one value per symbol for
 *       dep, centre, dep2 and centre2; 9 values for offsets) symbol i is coded with table
 *       ctx[i] + offsets[3 a + b], where a is 0, 1 or 2 as out[dep[i]] is below, equal to or above centre[i]
 *       (1 when dep[i] < 0), and b likewise for dep2 and centre2; a dependency must be an earlier symbol
 *       (learned-rans tables with context-coded MEAN tokens, FORMAT.md I.6.2); with adaptive, each row adapts
 *       to the symbols coded with it (adaptive rows, below) */
static uint32_t *ctx_cums(Py_buffer *fb, Py_ssize_t alphabet, Py_ssize_t *tables) {
    if (alphabet < 1 || alphabet > MAX_ALPHABET || fb->len % (4 * alphabet) || fb->len == 0) {
        PyErr_SetString(PyExc_ValueError, "freqs must be T x A uint32 values");
        return NULL;
    }
    *tables = fb->len / (4 * alphabet);
    uint32_t *cum = PyMem_Malloc(sizeof(uint32_t) * (size_t)(*tables) * (size_t)(alphabet + 1));
    if (!cum) {
        PyErr_NoMemory();
        return NULL;
    }
    const uint32_t *freqs = (const uint32_t *)fb->buf;
    for (Py_ssize_t t = 0; t < *tables; t++) {
        uint32_t *c = cum + t * (alphabet + 1);
        if (!build_cum(freqs + t * alphabet, alphabet, c)) {
            PyMem_Free(cum);
            PyErr_SetString(PyExc_ValueError, "a frequency table does not sum to 2^14");
            return NULL;
        }
        c[alphabet] = PROB_SCALE;
    }
    return cum;
}

/* Adaptive rows (FORMAT.md I.6.2, required flag bit 10): each row t of a stream keeps its own cumulative
 * counts at ADAPT_BITS precision, starting from the table's (cum << 2, over its symbol count n: the run of
 * positive frequencies), and after each symbol s coded with it moves them towards s by 1 / D, D = n + k + 3
 * for the row's k-th symbol (k from 0): cum[i] -= cum[i] / D for 1 <= i <= s, cum[i] += (2^16 - cum[i]) / D
 * for s < i < n.  The rANS start of symbol i is ((cum[i] * (2^14 - n)) >> 16) + i, so every frequency is >= 1
 * and they sum to 2^14. */
#define ADAPT_BITS 16
typedef struct {
    uint32_t *cum;   /* tables x (alphabet + 1) */
    uint32_t *n;     /* symbol count of each row */
    uint32_t *count; /* symbols coded with each row so far */
    Py_ssize_t stride;
} adapt_state;

static void adapt_free(adapt_state *a) {
    PyMem_Free(a->cum);
    PyMem_Free(a->n);
    PyMem_Free(a->count);
    a->cum = a->n = a->count = NULL;
}

/* 0 and a MemoryError when out of memory */
static int adapt_init(adapt_state *a, const uint32_t *freqs, Py_ssize_t tables, Py_ssize_t alphabet) {
    a->stride = alphabet + 1;
    a->cum = PyMem_Malloc(sizeof(uint32_t) * (size_t)tables * (size_t)(alphabet + 1));
    a->n = PyMem_Calloc((size_t)tables, sizeof(uint32_t));
    a->count = PyMem_Calloc((size_t)tables, sizeof(uint32_t));
    if (!a->cum || !a->n || !a->count) {
        adapt_free(a);
        PyErr_NoMemory();
        return 0;
    }
    for (Py_ssize_t t = 0; t < tables; t++) {
        const uint32_t *f = freqs + t * alphabet;
        uint32_t *c = a->cum + t * a->stride, acc = 0;
        Py_ssize_t n = 0;
        c[0] = 0;
        while (n < alphabet && f[n] > 0) {
            acc += f[n++];
            c[n] = acc << (ADAPT_BITS - PROB_BITS);
        }
        a->n[t] = (uint32_t)n;
    }
    return 1;
}

static ALWAYS_INLINE uint32_t adapt_start(const uint32_t *c, uint32_t n, uint32_t i) {
    return ((c[i] * (PROB_SCALE - n)) >> ADAPT_BITS) + i;
}

static ALWAYS_INLINE void adapt_update(adapt_state *a, Py_ssize_t t, uint32_t s) {
    uint32_t *c = a->cum + t * a->stride;
    const uint32_t n = a->n[t], d = n + a->count[t]++ + 3;
    for (uint32_t i = 1; i <= s; i++) c[i] -= c[i] / d;
    for (uint32_t i = s + 1; i < n; i++) c[i] += ((1u << ADAPT_BITS) - c[i]) / d;
}

static PyObject *rans_encode_ctx(PyObject *self, PyObject *args) {
    Py_buffer sb, xb, fb;
    Py_ssize_t alphabet, tables;
    int adaptive;
    if (!PyArg_ParseTuple(args, "y*y*y*np", &sb, &xb, &fb, &alphabet, &adaptive)) return NULL;
    PyObject *result = NULL;
    uint8_t *buf = NULL;
    uint32_t *cum = NULL, *starts = NULL;
    adapt_state ad = {0};
    if (sb.len % 2 || sb.len != xb.len) {
        PyErr_SetString(PyExc_ValueError, "symbols and ctx must be uint16 buffers of one length");
        goto done;
    }
    cum = ctx_cums(&fb, alphabet, &tables);
    if (!cum) goto done;
    const Py_ssize_t n = sb.len / 2;
    const uint16_t *sym = (const uint16_t *)sb.buf, *ctx = (const uint16_t *)xb.buf;
    const uint32_t *freqs = (const uint32_t *)fb.buf;
    const size_t cap = 2 * (size_t)n + 4;
    buf = PyMem_Malloc(cap);
    if (!buf) {
        PyErr_NoMemory();
        goto done;
    }
    uint8_t *p = buf + cap;
    uint32_t x = STATE_LOWER;
    int bad = 0;
    if (adaptive) { /* the forward pass: each symbol's (start, frequency) under its row's state then */
        starts = PyMem_Malloc(sizeof(uint32_t) * 2 * (size_t)(n ? n : 1));
        if (!starts) {
            PyErr_NoMemory();
            goto done;
        }
        if (!adapt_init(&ad, freqs, tables, alphabet)) goto done;
        for (Py_ssize_t k = 0; k < n; k++) {
            const Py_ssize_t t = ctx[k];
            const uint32_t s = sym[k];
            if (t >= tables || s >= ad.n[t]) {
                result = Py_NewRef(Py_None);
                goto done;
            }
            const uint32_t *c = ad.cum + t * ad.stride, lo = adapt_start(c, ad.n[t], s);
            starts[2 * k] = lo;
            starts[2 * k + 1] = adapt_start(c, ad.n[t], s + 1) - lo;
            adapt_update(&ad, t, s);
        }
    }
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t k = n - 1; k >= 0; k--) {
        const Py_ssize_t t = ctx[k], s = sym[k];
        uint32_t f, c;
        if (adaptive) {
            c = starts[2 * k];
            f = starts[2 * k + 1];
        } else {
            if (t >= tables || s >= alphabet || freqs[t * alphabet + s] == 0) {
                bad = 1;
                break;
            }
            f = freqs[t * alphabet + s];
            c = cum[t * (alphabet + 1) + s];
        }
        const uint32_t x_max = f << UPPER_SHIFT;
        while (x >= x_max) {
            *--p = (uint8_t)x;
            x >>= 8;
        }
        x = ((x / f) << PROB_BITS) + (x % f) + c;
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
    PyMem_Free(buf);
    PyMem_Free(cum);
    PyMem_Free(starts);
    adapt_free(&ad);
    PyBuffer_Release(&sb);
    PyBuffer_Release(&xb);
    PyBuffer_Release(&fb);
    return result;
}

/* 0, 1 or 2 as the symbol decoded at dep is below, equal to or above centre; 1 when dep < 0 (no dependency);
 * -1 when dep is not an earlier symbol than i */
static inline int compare_dependency(const uint16_t *out, int32_t dep, uint16_t centre, Py_ssize_t i) {
    if (dep < 0) return 1;
    if (dep >= i) return -1;
    return out[dep] < centre ? 0 : out[dep] > centre ? 2 : 1;
}

static PyObject *rans_decode_ctx(PyObject *self, PyObject *args) {
    Py_buffer sb, xb, fb, ob;
    Py_buffer db = {0}, cb = {0}, db2 = {0}, cb2 = {0}, offb = {0};
    Py_ssize_t alphabet, tables;
    int adaptive;
    if (!PyArg_ParseTuple(args, "y*y*y*npw*|y*y*y*y*y*", &sb, &xb, &fb, &alphabet, &adaptive, &ob, &db, &cb, &db2,
                          &cb2, &offb))
        return NULL;
    PyObject *result = NULL;
    uint32_t *cum = NULL;
    adapt_state ad = {0};
    const int dependent = db.buf != NULL;
    if (ob.len % 2 || ob.len != xb.len || sb.len < 4) {
        PyErr_SetString(PyExc_ValueError, "out and ctx must be uint16 buffers of one length, the stream >= 4 bytes");
        goto done;
    }
    if (dependent && (db.len != 2 * ob.len || cb.buf == NULL || db2.buf == NULL || cb2.buf == NULL
                      || offb.buf == NULL || cb.len != ob.len || db2.len != 2 * ob.len || cb2.len != ob.len
                      || offb.len != 9 * 4)) {
        PyErr_SetString(PyExc_ValueError, "dep, dep2 (int32), centre, centre2 (uint16) need one value per symbol, "
                        "offsets (int32) 9 values");
        goto done;
    }
    cum = ctx_cums(&fb, alphabet, &tables);
    if (!cum) goto done;
    if (adaptive && !adapt_init(&ad, (const uint32_t *)fb.buf, tables, alphabet)) goto done;
    const uint8_t *data = (const uint8_t *)sb.buf;
    const uint16_t *ctx = (const uint16_t *)xb.buf;
    const uint32_t *freqs = (const uint32_t *)fb.buf;
    uint16_t *out = (uint16_t *)ob.buf;
    const int32_t *dep = (const int32_t *)db.buf, *dep2 = (const int32_t *)db2.buf,
                  *offsets = (const int32_t *)offb.buf;
    const uint16_t *centre = (const uint16_t *)cb.buf, *centre2 = (const uint16_t *)cb2.buf;
    const Py_ssize_t n = ob.len / 2, end = sb.len;
    uint32_t x = read_u32(data);
    Py_ssize_t pos = 4, i = 0;
    int bad_ctx = 0;
    Py_BEGIN_ALLOW_THREADS
    for (; i < n; i++) {
        Py_ssize_t t = ctx[i];
        if (dependent) {
            const int a = compare_dependency(out, dep[i], centre[i], i), b = compare_dependency(out, dep2[i], centre2[i], i);
            if (a < 0 || b < 0) {
                bad_ctx = 1;
                break;
            }
            t += offsets[3 * a + b];
        }
        if (t < 0 || t >= tables) {
            bad_ctx = 1;
            break;
        }
        const uint32_t slot = x & (PROB_SCALE - 1);
        uint32_t lo = 0, start, f; /* the symbol lo with start <= slot < start + f */
        if (adaptive) { /* under the row's present state */
            const uint32_t *c = ad.cum + t * ad.stride, rn = ad.n[t];
            uint32_t hi = rn;
            while (hi - lo > 1) {
                const uint32_t mid = (lo + hi) / 2;
                if (adapt_start(c, rn, mid) <= slot) lo = mid;
                else hi = mid;
            }
            start = adapt_start(c, rn, lo);
            f = adapt_start(c, rn, lo + 1) - start;
            adapt_update(&ad, t, lo);
        } else {
            const uint32_t *c = cum + t * (alphabet + 1);
            uint32_t hi = (uint32_t)alphabet;
            while (hi - lo > 1) {
                const uint32_t mid = (lo + hi) / 2;
                if (c[mid] <= slot) lo = mid;
                else hi = mid;
            }
            start = c[lo];
            f = freqs[t * alphabet + lo];
        }
        x = f * (x >> PROB_BITS) + slot - start;
        while (x < STATE_LOWER) {
            if (pos >= end) goto stop;
            x = (x << 8) | data[pos++];
        }
        out[i] = (uint16_t)lo;
    }
stop:
    Py_END_ALLOW_THREADS
    if (bad_ctx) {
        PyErr_SetString(PyExc_ValueError, "a context index lies outside the tables, or a dependency is not earlier");
        goto done;
    }
    result = Py_BuildValue("(nnk)", i, pos, (unsigned long)x);
done:
    PyMem_Free(cum);
    adapt_free(&ad);
    PyBuffer_Release(&sb);
    PyBuffer_Release(&xb);
    PyBuffer_Release(&fb);
    PyBuffer_Release(&ob);
    if (db.buf) PyBuffer_Release(&db);
    if (cb.buf) PyBuffer_Release(&cb);
    if (db2.buf) PyBuffer_Release(&db2);
    if (cb2.buf) PyBuffer_Release(&cb2);
    if (offb.buf) PyBuffer_Release(&offb);
    return result;
}

static PyMethodDef methods[] = {
    {"decode", rans_decode, METH_VARARGS,
     "decode(stream, freqs_u32, out_u16[, lanes]) -> (symbols_decoded, stream_pos, final_states)"},
    {"decode_mapped", rans_decode_mapped, METH_VARARGS,
     "decode_mapped(((stream, freqs_u32, out_f32, cols, colbase_u32, lut_f32, centre_u8_or_empty, top[, lanes]),"
     " ...)) -> [(symbols_decoded, stream_pos, final_states, bad_code), ...] for 1 or 2 streams"},
    {"encode", rans_encode, METH_VARARGS,
     "encode(((symbols_u16, freqs_u32[, lanes]), ...)) -> [stream bytes, or None if a symbol has frequency 0,"
     " ...] for 1 or 2 streams"},
    {"column_histograms", column_histograms, METH_VARARGS,
     "column_histograms(codes_u8, cols, size, out_i64): count code v of column c into out[c * size + v]"},
    {"quaternions_to_rotations", quaternions_to_rotations, METH_VARARGS,
     "quaternions_to_rotations(q_f64, out_f64) -> True, or None where binary64 is not exact: FORMAT.md I.5.2's "
     "rotations of n quaternions (w, x, y, z)"},
    {"rotations_to_quaternions", rotations_to_quaternions, METH_VARARGS,
     "rotations_to_quaternions(R_f64, continuous, out_f64) -> True, or None (a non-finite value, or binary64 not "
     "exact): compact_cameras.rotation_to_quaternion's quaternions, the same operations"},
    {"cameras_valid", cameras_valid, METH_VARARGS,
     "cameras_valid(K_f64, w2c_f64, timestamps_f64) -> bool: True where the decoded cameras plainly satisfy the "
     "camera conventions (False: let the numpy checks decide)"},
    {"dequantize_u8", dequantize_u8, METH_VARARGS,
     "dequantize_u8(codes_u8, cols, scale_f32, offset_f32, out_f32) -> bool: out[r, c] = f32(f64(offset[c]) + "
     "f64(scale[c]) * codes[r, c]); False (nothing written) where a table value is not a finite float32"},
    {"encode_ctx", rans_encode_ctx, METH_VARARGS,
     "encode_ctx(symbols_u16, ctx_u16, freqs_u32, A, adaptive) -> stream bytes, or None if a symbol has frequency 0"},
    {"decode_ctx", rans_decode_ctx, METH_VARARGS,
     "decode_ctx(stream, ctx_u16, freqs_u32, A, adaptive, out_u16[, dep_i32, centre_u16, dep2_i32, centre2_u16, "
     "offsets_i32]) -> (symbols_decoded, stream_pos, final_state)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_rans_native",
                                    "The rANS coder of FORMAT.md I.6.1 in C (see rans.py).", -1, methods};

PyMODINIT_FUNC PyInit__rans_native(void) { return PyModule_Create(&module); }
