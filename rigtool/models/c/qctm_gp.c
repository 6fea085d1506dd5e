/* Reference C evaluator of an exported QCTM-GP thrust model (qctm_gp.json, format 2-7).
 *
 * Build:  cc -std=c99 -O2 -o qctm_eval qctm_gp.c qctm_eval_main.c -lm
 *
 * C99, libc and libm only. It reproduces rigtool.models.ThrustModel.evaluate
 * (rigtool/models/qctm.py, betm.py, domain.py are the reference), operation by operation
 * where the order matters for rounding; sums over training rows differ from numpy's BLAS
 * order only in the last bits. Contents:
 *   1. a minimal JSON reader (objects, arrays, numbers, strings, true/false/null and
 *      Python's NaN/Infinity extensions),
 *   2. a .npy reader for the posterior-variance matrix ('<f8', shape (n, n)),
 *   3. the model: loading and checking the document,
 *   4. evaluation: shortfall, window, BETM fusion, GP mean and variance, bounds, domain.
 */
#include "qctm_gp.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define SQRT5 2.23606797749979 /* 5.0 ** 0.5 in Python */
#define MAX_DEPTH 200          /* JSON nesting limit: bad input must not exhaust the stack */
#define MAX_MODEL_VALUE 1e6    /* |input, centre or level| (MAX_MODEL_VALUE in qctm.py) */
#define MIN_MODEL_SCALE 1e-6   /* smallest scale a standardisation divides by (qctm.py) */
#define MAX_KERNEL_WEIGHT 1e12 /* |alpha| of the noise GP (MAX_KERNEL_WEIGHT in qctm.py) */

static void set_err(char *err, size_t errlen, const char *fmt, ...)
{
    va_list ap;
    if (err == NULL || errlen == 0)
        return;
    va_start(ap, fmt);
    vsnprintf(err, errlen, fmt, ap);
    va_end(ap);
}

/* ---------------------------------------------------------------- 1. JSON reader */

typedef enum { J_NULL, J_FALSE, J_TRUE, J_NUM, J_STR, J_ARR, J_OBJ } jtype;

typedef struct jval {
    jtype type;
    double num;          /* J_NUM */
    char *str;           /* J_STR: bytes, NUL-terminated */
    size_t len;          /* J_STR: bytes; J_ARR, J_OBJ: items */
    struct jval *items;  /* J_ARR, J_OBJ: values */
    char **keys;         /* J_OBJ: keys (NUL-terminated) */
    size_t *key_len;     /* J_OBJ: key lengths (a key may hold \u0000) */
} jval;

typedef struct {
    const char *start, *p, *end;
    char *err;
    size_t errlen;
} jparser;

static void jfree(jval *v)
{
    size_t i;
    if (v->type == J_ARR || v->type == J_OBJ) {
        for (i = 0; i < v->len; i++) {
            jfree(&v->items[i]);
            if (v->keys != NULL)
                free(v->keys[i]);
        }
    }
    free(v->items);
    free(v->keys);
    free(v->key_len);
    free(v->str);
    memset(v, 0, sizeof *v);
}

/* Error at the parser's position, as "line L, column C: message". */
static int jfail(jparser *P, const char *what)
{
    size_t line = 1, col = 1;
    const char *q;
    for (q = P->start; q < P->p && q < P->end; q++) {
        if (*q == '\n') {
            line++;
            col = 1;
        } else {
            col++;
        }
    }
    set_err(P->err, P->errlen, "line %lu, column %lu: %s", (unsigned long)line,
            (unsigned long)col, what);
    return -1;
}

static void jskip_ws(jparser *P)
{
    while (P->p < P->end && (*P->p == ' ' || *P->p == '\t' || *P->p == '\n' || *P->p == '\r'))
        P->p++;
}

static int jlit(jparser *P, const char *word)
{
    size_t n = strlen(word);
    if ((size_t)(P->end - P->p) >= n && memcmp(P->p, word, n) == 0) {
        P->p += n;
        return 1;
    }
    return 0;
}

static int hex4(const char *s, unsigned *out)
{
    unsigned v = 0;
    int i;
    for (i = 0; i < 4; i++) {
        char c = s[i];
        v <<= 4;
        if (c >= '0' && c <= '9')
            v |= (unsigned)(c - '0');
        else if (c >= 'a' && c <= 'f')
            v |= (unsigned)(c - 'a' + 10);
        else if (c >= 'A' && c <= 'F')
            v |= (unsigned)(c - 'A' + 10);
        else
            return -1;
    }
    *out = v;
    return 0;
}

static size_t utf8_put(char *o, unsigned cp)
{
    if (cp < 0x80) {
        o[0] = (char)cp;
        return 1;
    }
    if (cp < 0x800) {
        o[0] = (char)(0xC0 | (cp >> 6));
        o[1] = (char)(0x80 | (cp & 0x3F));
        return 2;
    }
    if (cp < 0x10000) {
        o[0] = (char)(0xE0 | (cp >> 12));
        o[1] = (char)(0x80 | ((cp >> 6) & 0x3F));
        o[2] = (char)(0x80 | (cp & 0x3F));
        return 3;
    }
    o[0] = (char)(0xF0 | (cp >> 18));
    o[1] = (char)(0x80 | ((cp >> 12) & 0x3F));
    o[2] = (char)(0x80 | ((cp >> 6) & 0x3F));
    o[3] = (char)(0x80 | (cp & 0x3F));
    return 4;
}

/* A string at P->p (on the opening quote); the decoded bytes need at most as many bytes
 * as the escaped text, so one buffer of the remaining length suffices. */
static int jstring(jparser *P, char **out, size_t *out_len)
{
    const char *q = P->p + 1;
    size_t n = 0;
    char *buf;
    while (q < P->end && *q != '"')
        q += (*q == '\\' && q + 1 < P->end) ? 2 : 1;
    if (q >= P->end)
        return jfail(P, "unterminated string");
    buf = malloc((size_t)(q - P->p) + 1);
    if (buf == NULL)
        return jfail(P, "out of memory");
    P->p++;
    while (*P->p != '"') {
        unsigned char c = (unsigned char)*P->p;
        if (c < 0x20) {
            free(buf);
            return jfail(P, "control character in string");
        }
        if (c != '\\') {
            buf[n++] = (char)c;
            P->p++;
            continue;
        }
        P->p++;
        switch (*P->p) {
        case '"': buf[n++] = '"'; break;
        case '\\': buf[n++] = '\\'; break;
        case '/': buf[n++] = '/'; break;
        case 'b': buf[n++] = '\b'; break;
        case 'f': buf[n++] = '\f'; break;
        case 'n': buf[n++] = '\n'; break;
        case 'r': buf[n++] = '\r'; break;
        case 't': buf[n++] = '\t'; break;
        case 'u': {
            unsigned cp, lo;
            if (P->end - P->p < 5 || hex4(P->p + 1, &cp) != 0) {
                free(buf);
                return jfail(P, "bad \\u escape");
            }
            P->p += 4;
            /* a surrogate pair \uD8xx\uDCxx is one code point */
            if (cp >= 0xD800 && cp < 0xDC00 && P->end - P->p >= 7 && P->p[1] == '\\'
                && P->p[2] == 'u' && hex4(P->p + 3, &lo) == 0 && lo >= 0xDC00 && lo < 0xE000) {
                cp = 0x10000 + ((cp - 0xD800) << 10) + (lo - 0xDC00);
                P->p += 6;
            }
            n += utf8_put(buf + n, cp);
            break;
        }
        default:
            free(buf);
            return jfail(P, "bad escape in string");
        }
        P->p++;
    }
    P->p++;
    buf[n] = '\0';
    *out = buf;
    *out_len = n;
    return 0;
}

/* A number (JSON grammar, checked here; converted by strtod in the C locale). */
static int jnumber(jparser *P, double *out)
{
    const char *s = P->p, *q = P->p;
    char small[64], *buf = small;
    size_t n;
    if (q < P->end && *q == '-')
        q++;
    if (q < P->end && *q == '0') {
        q++;
    } else if (q < P->end && *q >= '1' && *q <= '9') {
        while (q < P->end && *q >= '0' && *q <= '9')
            q++;
    } else {
        return jfail(P, "bad number");
    }
    if (q < P->end && *q == '.') {
        q++;
        if (q >= P->end || *q < '0' || *q > '9')
            return jfail(P, "bad number: digits expected after '.'");
        while (q < P->end && *q >= '0' && *q <= '9')
            q++;
    }
    if (q < P->end && (*q == 'e' || *q == 'E')) {
        q++;
        if (q < P->end && (*q == '+' || *q == '-'))
            q++;
        if (q >= P->end || *q < '0' || *q > '9')
            return jfail(P, "bad number: digits expected in the exponent");
        while (q < P->end && *q >= '0' && *q <= '9')
            q++;
    }
    n = (size_t)(q - s);
    if (n >= sizeof small && (buf = malloc(n + 1)) == NULL)
        return jfail(P, "out of memory");
    memcpy(buf, s, n);
    buf[n] = '\0';
    *out = strtod(buf, NULL); /* overflow gives +-inf, as Python's float() */
    if (buf != small)
        free(buf);
    P->p = q;
    return 0;
}

static int jvalue(jparser *P, jval *v, int depth);

/* Append a parsed item (and its key, for objects) to an array or object. */
static int jpush(jparser *P, jval *v, size_t *cap, jval *item, char *key, size_t key_len)
{
    if (v->len == *cap) {
        size_t nc = *cap ? 2 * *cap : 4;
        jval *items = realloc(v->items, nc * sizeof *items);
        if (items == NULL)
            return jfail(P, "out of memory");
        v->items = items;
        if (v->type == J_OBJ) {
            char **keys = realloc(v->keys, nc * sizeof *keys);
            size_t *lens;
            if (keys == NULL)
                return jfail(P, "out of memory");
            v->keys = keys;
            lens = realloc(v->key_len, nc * sizeof *lens);
            if (lens == NULL)
                return jfail(P, "out of memory");
            v->key_len = lens;
        }
        *cap = nc;
    }
    v->items[v->len] = *item;
    if (v->type == J_OBJ) {
        v->keys[v->len] = key;
        v->key_len[v->len] = key_len;
    }
    v->len++;
    return 0;
}

/* An array or object; P->p is on '[' or '{'. On failure the caller frees v. */
static int jcontainer(jparser *P, jval *v, int depth)
{
    int obj = *P->p == '{';
    char close = obj ? '}' : ']';
    size_t cap = 0;
    v->type = obj ? J_OBJ : J_ARR;
    if (depth >= MAX_DEPTH)
        return jfail(P, "nested too deeply");
    P->p++;
    jskip_ws(P);
    if (P->p < P->end && *P->p == close) {
        P->p++;
        return 0;
    }
    for (;;) {
        jval item;
        char *key = NULL;
        size_t key_len = 0;
        memset(&item, 0, sizeof item);
        jskip_ws(P);
        if (obj) {
            if (P->p >= P->end || *P->p != '"')
                return jfail(P, "expected a string key");
            if (jstring(P, &key, &key_len) != 0)
                return -1;
            jskip_ws(P);
            if (P->p >= P->end || *P->p != ':') {
                free(key);
                return jfail(P, "expected ':'");
            }
            P->p++;
        }
        if (jvalue(P, &item, depth + 1) != 0 || jpush(P, v, &cap, &item, key, key_len) != 0) {
            jfree(&item);
            free(key);
            return -1;
        }
        jskip_ws(P);
        if (P->p < P->end && *P->p == ',') {
            P->p++;
            continue;
        }
        if (P->p < P->end && *P->p == close) {
            P->p++;
            return 0;
        }
        return jfail(P, obj ? "expected ',' or '}'" : "expected ',' or ']'");
    }
}

static int jvalue(jparser *P, jval *v, int depth)
{
    jskip_ws(P);
    if (P->p >= P->end)
        return jfail(P, "unexpected end of input");
    switch (*P->p) {
    case '{':
    case '[':
        return jcontainer(P, v, depth);
    case '"':
        v->type = J_STR;
        return jstring(P, &v->str, &v->len);
    default:
        break;
    }
    v->type = J_NUM;
    if (jlit(P, "null")) {
        v->type = J_NULL;
    } else if (jlit(P, "true")) {
        v->type = J_TRUE;
    } else if (jlit(P, "false")) {
        v->type = J_FALSE;
    } else if (jlit(P, "NaN")) { /* Python's json writes these unless allow_nan=False */
        v->num = NAN;
    } else if (jlit(P, "Infinity")) {
        v->num = INFINITY;
    } else if (jlit(P, "-Infinity")) {
        v->num = -INFINITY;
    } else {
        return jnumber(P, &v->num);
    }
    return 0;
}

/* Parse a whole document; nothing but whitespace may follow the value. */
static int jparse(const char *text, size_t size, jval *root, char *err, size_t errlen)
{
    jparser P;
    P.start = P.p = text;
    P.end = text + size;
    P.err = err;
    P.errlen = errlen;
    memset(root, 0, sizeof *root);
    if (jvalue(&P, root, 0) != 0) {
        jfree(root);
        return -1;
    }
    jskip_ws(&P);
    if (P.p != P.end) {
        jfree(root);
        return jfail(&P, "extra data after the JSON value");
    }
    return 0;
}

/* Member `name` of an object (the last one if repeated, as Python's json), or NULL. */
static const jval *jget(const jval *obj, const char *name)
{
    size_t i = obj != NULL && obj->type == J_OBJ ? obj->len : 0, n = strlen(name);
    while (i-- > 0) {
        if (obj->key_len[i] == n && memcmp(obj->keys[i], name, n) == 0)
            return &obj->items[i];
    }
    return NULL;
}

/* --------------------------------------------------------------- 2. .npy reader */

/* Read a file into memory (NUL-terminated). Returns NULL and sets *missing when the file
 * does not exist, NULL with a message for other errors. */
static char *read_file(const char *path, size_t *size, int *missing, char *err, size_t errlen)
{
    FILE *f;
    char *buf = NULL;
    size_t cap = 0, n = 0;
    *missing = 0;
    errno = 0;
    f = fopen(path, "rb");
    if (f == NULL) {
        *missing = errno == ENOENT;
        set_err(err, errlen, "%s: %s", path, strerror(errno));
        return NULL;
    }
    for (;;) {
        size_t got;
        if (cap - n < 65536) {
            char *nb = realloc(buf, cap + (cap > 65536 ? cap : 65536) + 1);
            if (nb == NULL) {
                free(buf);
                fclose(f);
                set_err(err, errlen, "%s: out of memory", path);
                return NULL;
            }
            buf = nb;
            cap += cap > 65536 ? cap : 65536;
        }
        got = fread(buf + n, 1, cap - n, f);
        n += got;
        if (got == 0)
            break;
    }
    if (ferror(f)) {
        free(buf);
        fclose(f);
        set_err(err, errlen, "%s: read error", path);
        return NULL;
    }
    fclose(f);
    buf[n] = '\0';
    *size = n;
    return buf;
}

/* Value text after 'key': in a .npy header (a Python dict literal), or NULL. */
static const char *npy_field(const char *hdr, const char *key)
{
    char pat[32];
    const char *q;
    int k;
    for (k = 0; k < 2; k++) {
        snprintf(pat, sizeof pat, k ? "\"%s\"" : "'%s'", key);
        if ((q = strstr(hdr, pat)) != NULL) {
            q += strlen(pat);
            while (*q == ' ')
                q++;
            if (*q != ':')
                return NULL;
            q++;
            while (*q == ' ')
                q++;
            return q;
        }
    }
    return NULL;
}

/* The n x n posterior-variance matrix from a .npy file (format 1.0-3.0, '<f8', C or
 * Fortran order; the matrix is stored row-major in *out). */
static int read_npy(const char *path, size_t n, double **out, int *missing, char *err,
                    size_t errlen)
{
    size_t size, hlen, start, dims[2], nd = 0, i, j;
    int fortran;
    char *buf = read_file(path, &size, missing, err, errlen), *hdr;
    const char *q;
    const unsigned char *u = (const unsigned char *)buf;
    double *m;
    if (buf == NULL)
        return -1;
    if (size < 10 || memcmp(buf, "\x93NUMPY", 6) != 0 || u[6] < 1 || u[6] > 3) {
        set_err(err, errlen, "%s: not a .npy file (version 1-3)", path);
        free(buf);
        return -1;
    }
    if (u[6] == 1) {
        hlen = (size_t)u[8] | (size_t)u[9] << 8;
        start = 10;
    } else {
        hlen = size < 12 ? 0 : (size_t)u[8] | (size_t)u[9] << 8 | (size_t)u[10] << 16
                                   | (size_t)u[11] << 24;
        start = 12;
    }
    if (size < start + hlen || hlen == 0) {
        set_err(err, errlen, "%s: truncated .npy header", path);
        free(buf);
        return -1;
    }
    hdr = malloc(hlen + 1);
    if (hdr == NULL) {
        set_err(err, errlen, "%s: out of memory", path);
        free(buf);
        return -1;
    }
    memcpy(hdr, buf + start, hlen);
    hdr[hlen] = '\0';
    start += hlen;
    /* {'descr': '<f8', 'fortran_order': False, 'shape': (n, n), } */
    q = npy_field(hdr, "descr");
    if (q == NULL || (strncmp(q, "'<f8'", 5) != 0 && strncmp(q, "\"<f8\"", 5) != 0)) {
        set_err(err, errlen, "%s: dtype must be '<f8' (little-endian float64)", path);
        goto fail;
    }
    q = npy_field(hdr, "fortran_order");
    if (q == NULL || (strncmp(q, "False", 5) != 0 && strncmp(q, "True", 4) != 0)) {
        set_err(err, errlen, "%s: no fortran_order in the .npy header", path);
        goto fail;
    }
    fortran = *q == 'T';
    q = npy_field(hdr, "shape");
    if (q == NULL || *q != '(') {
        set_err(err, errlen, "%s: no shape in the .npy header", path);
        goto fail;
    }
    for (q++; *q == ' '; q++)
        ;
    while (*q != ')') { /* "n, n" with an optional trailing comma */
        char *e;
        if (*q < '0' || *q > '9' || nd == 2)
            break;
        dims[nd++] = (size_t)strtoul(q, &e, 10);
        for (q = e; *q == ' ' || *q == ','; q++)
            ;
    }
    if (*q != ')' || nd != 2 || dims[0] != n || dims[1] != n) {
        set_err(err, errlen, "%s: shape must be (%lu, %lu), the number of gp.x_train rows",
                path, (unsigned long)n, (unsigned long)n);
        goto fail;
    }
    if ((size - start) / 8 / n < n) {
        set_err(err, errlen, "%s: %lu data bytes, %lu x %lu float64 expected", path,
                (unsigned long)(size - start), (unsigned long)n, (unsigned long)n);
        goto fail;
    }
    m = malloc(n * n * sizeof *m);
    if (m == NULL) {
        set_err(err, errlen, "%s: out of memory", path);
        goto fail;
    }
    for (i = 0; i < n; i++) {
        for (j = 0; j < n; j++) {
            /* little-endian bytes to a double, whatever the host's byte order */
            const unsigned char *b = u + start + 8 * (i * n + j);
            unsigned long long bits = 0;
            int k;
            for (k = 7; k >= 0; k--)
                bits = bits << 8 | b[k];
            memcpy(fortran ? &m[j * n + i] : &m[i * n + j], &bits, sizeof(double));
        }
    }
    for (i = 0; i < n * n; i++) {
        if (!isfinite(m[i]) || fabs(m[i]) > MAX_KERNEL_WEIGHT) {
            set_err(err, errlen, "%s: entries must be finite and within -1e+12..1e+12 (the "
                    "posterior variance would be NaN)", path);
            free(m);
            goto fail;
        }
    }
    free(hdr);
    free(buf);
    *out = m;
    return 0;
fail:
    free(hdr);
    free(buf);
    return -1;
}

/* --------------------------------------------------------------------- 3. model */

/* A sum of Matern-5/2 terms over training rows: sum_j w_j m(r_j), r_j the distance of
 * the standardised input to row j in length-scale units (the GP mean, the log noise). */
typedef struct {
    size_t n;
    double x_mean[3], x_scale[3], ls[3];
    double *xt; /* standardised training rows (x_train - x_mean) / x_scale, n x 3 */
    double *w;  /* gp.a_n, or noise.alpha; NULL for a GP without signal (no mean terms) */
} kernel_sum;

struct qctm_model {
    int version;
    /* BETM (models/betm.py) */
    double cp_fwd, cp_rev, c_n, i_0, ci_fwd, ci_rev, sigma_n, sigma_i, u0, sigma0, gamma;
    size_t n_level;
    double *level_n, *sigma_n_level, *sigma_i_level;
    /* features: shortfall window reaching half_hi blocks ahead and half_lo back */
    long long window, half_hi, half_lo;
    /* GP */
    kernel_sum gp;
    int has_signal; /* 0: format 6 "signal": false, no GP mean or posterior terms */
    double signal_var, noise_var, y_mean, y_std, beta, gate_z0, gate_s;
    double *kinv; /* n x n, or NULL: prior variance */
    /* heteroscedastic noise */
    int has_noise;
    kernel_sum noise;
    double noise_signal_var, log_mean, log_bias;
    /* format 5: bias log_bias + (log_bias_event - log_bias) gate(z) with the noise's own gate */
    int has_bias_event;
    double log_bias_event, noise_gate_z0, noise_gate_s;
    /* format 7: loss-side widening (1 - gate(z)) * interp(|n|, missed_rpm, missed_lower) */
    size_t n_missed;
    double *missed_rpm, *missed_lower;
    /* bounds and domain (models/domain.py) */
    double short_lo, short_hi, above_n;
    int has_domain, has_range[4];
    double range_lo[4], range_hi[4], max_distance;
    /* 1: trained on two runs or more, its 95 % intervals checked run by run; 0: one run;
     * -1: not recorded (files written before intervals_validated) */
    int intervals_validated;
};

static const char *const DOMAIN_INPUTS[4] = {"speed_rpm", "current_a", "depth_m",
                                             "shortfall_thrust_n"};

typedef struct {
    char *err;
    size_t errlen;
} loader;

static int lfail(loader *L, const char *fmt, const char *name)
{
    set_err(L->err, L->errlen, fmt, name);
    return -1;
}

/* A number member; `def` is used when absent (NAN def: required). */
static int get_num(loader *L, const jval *obj, const char *name, double def, double *out)
{
    const jval *v = jget(obj, name);
    if (v == NULL) {
        if (isnan(def))
            return lfail(L, "qctm_gp.json: missing %s", name);
        *out = def;
        return 0;
    }
    if (v->type != J_NUM)
        return lfail(L, "qctm_gp.json: %s must be a number", name);
    *out = v->num;
    return 0;
}

/* An integer member as Python's int(): a number truncated towards zero. */
static int get_int(loader *L, const jval *v, const char *name, long long *out)
{
    if (v->type != J_NUM || !isfinite(v->num) || fabs(v->num) > 9e15)
        return lfail(L, "qctm_gp.json: %s must be a finite integer", name);
    *out = (long long)v->num;
    return 0;
}

/* A numeric array of any length (*out malloc'ed, *n its length). */
static int get_vec(loader *L, const jval *v, const char *name, double **out, size_t *n)
{
    size_t i;
    if (v == NULL || v->type != J_ARR)
        return lfail(L, "qctm_gp.json: %s must be an array of numbers", name);
    *out = malloc((v->len ? v->len : 1) * sizeof **out);
    if (*out == NULL)
        return lfail(L, "qctm_gp.json: out of memory reading %s", name);
    for (i = 0; i < v->len; i++) {
        if (v->items[i].type != J_NUM) {
            free(*out);
            *out = NULL;
            return lfail(L, "qctm_gp.json: %s must be an array of numbers", name);
        }
        (*out)[i] = v->items[i].num;
    }
    *n = v->len;
    return 0;
}

/* Three per-input values; a number or a one-element array applies to all three inputs
 * (numpy broadcasting). */
static int get_vec3(loader *L, const jval *obj, const char *what, const char *key,
                    double out[3])
{
    const jval *v = jget(obj, key);
    char name[64];
    double *a;
    size_t n, k;
    snprintf(name, sizeof name, "%s.%s", what, key);
    if (v != NULL && v->type == J_NUM) {
        out[0] = out[1] = out[2] = v->num;
        return 0;
    }
    if (get_vec(L, v, name, &a, &n) != 0)
        return -1;
    if (n != 1 && n != 3) {
        free(a);
        return lfail(L, "qctm_gp.json: %s must have 3 elements", name);
    }
    for (k = 0; k < 3; k++)
        out[k] = a[n == 1 ? 0 : k];
    free(a);
    return 0;
}

/* Training rows (n x 3) of a kernel sum, standardised; its weights w are left NULL. */
static int get_rows(loader *L, const jval *obj, const char *what, kernel_sum *ks)
{
    const jval *rows = jget(obj, "x_train");
    char name[64];
    size_t j, k;
    if (get_vec3(L, obj, what, "x_mean", ks->x_mean) != 0
        || get_vec3(L, obj, what, "x_scale", ks->x_scale) != 0
        || get_vec3(L, obj, what, "length_scales", ks->ls) != 0)
        return -1;
    /* bounded, so that standardising and squaring cannot overflow into NaN intervals */
    for (k = 0; k < 3; k++) {
        const char *bad = !(fabs(ks->x_mean[k]) <= MAX_MODEL_VALUE) ? "x_mean"
            : !(ks->x_scale[k] >= MIN_MODEL_SCALE && ks->x_scale[k] <= MAX_MODEL_VALUE) ? "x_scale"
            : !(ks->ls[k] >= MIN_MODEL_SCALE && ks->ls[k] <= MAX_MODEL_VALUE) ? "length_scales"
            : NULL;
        if (bad != NULL) {
            snprintf(name, sizeof name, "%s.%s", what, bad);
            return lfail(L, "qctm_gp.json: %s must be finite and within its bounds "
                         "(|x_mean| <= 1e6, scales 1e-6..1e6)", name);
        }
    }
    snprintf(name, sizeof name, "%s.x_train", what);
    if (rows == NULL || rows->type != J_ARR || rows->len == 0)
        return lfail(L, "qctm_gp.json: %s must be a non-empty array of rows", name);
    ks->n = rows->len;
    ks->xt = malloc(ks->n * 3 * sizeof *ks->xt);
    if (ks->xt == NULL)
        return lfail(L, "qctm_gp.json: out of memory reading %s", name);
    for (j = 0; j < ks->n; j++) {
        const jval *r = &rows->items[j];
        if (r->type != J_ARR || r->len != 3)
            return lfail(L, "qctm_gp.json: every row of %s must have 3 numbers", name);
        for (k = 0; k < 3; k++) {
            if (r->items[k].type != J_NUM)
                return lfail(L, "qctm_gp.json: every row of %s must have 3 numbers", name);
            if (!(fabs(r->items[k].num) <= MAX_MODEL_VALUE))
                return lfail(L, "qctm_gp.json: %s must be finite and within -1e6..1e6", name);
            ks->xt[3 * j + k] = (r->items[k].num - ks->x_mean[k]) / ks->x_scale[k];
        }
    }
    return 0;
}

/* Training rows (n x 3) and their per-row weights w of a kernel sum. */
static int get_kernel(loader *L, const jval *obj, const char *what, const char *w_name,
                      kernel_sum *ks)
{
    char name[64];
    size_t nw;
    if (get_rows(L, obj, what, ks) != 0)
        return -1;
    snprintf(name, sizeof name, "%s.%s", what, w_name);
    if (get_vec(L, jget(obj, w_name), name, &ks->w, &nw) != 0)
        return -1;
    if (nw != ks->n)
        return lfail(L, "qctm_gp.json: %s must have one value per x_train row", name);
    return 0;
}

/* A scalar of the gp section within lo..MAX_MODEL_VALUE (model_from_document's bounds). */
static int check_range(loader *L, double v, double lo, const char *name)
{
    if (v >= lo && v <= MAX_MODEL_VALUE)
        return 0;
    return lfail(L, "qctm_gp.json: %s must be finite and within its bounds "
                 "(|value| <= 1e6; scales and variances >= 0)", name);
}

/* The noise model's weights (LogNoise.from_dict; its inputs are bounded by get_rows): finite
 * and bounded, else NaN or infinite intervals instead of a refusal. */
static int check_noise_kernel(loader *L, const kernel_sum *ks)
{
    size_t i;
    for (i = 0; i < ks->n; i++)
        if (!(fabs(ks->w[i]) <= MAX_KERNEL_WEIGHT))
            return lfail(L, "qctm_gp.json: %s", "noise.alpha must be finite and within "
                         "-1e12..1e12");
    return 0;
}

static int load_betm(loader *L, qctm_model *m, const jval *b)
{
    static const char *const known[] = {"cp_fwd", "cp_rev", "c_n", "i_0", "ci_fwd", "ci_rev",
                                        "sigma_n", "sigma_i", "sigma_meas", "u0", "sigma0",
                                        "gamma", "level_n", "sigma_n_level", "sigma_i_level"};
    size_t i, k, n1, n2;
    if (b == NULL || b->type != J_OBJ)
        return lfail(L, "qctm_gp.json: %s must be an object", "betm");
    /* Python builds Betm(**betm): an unknown field is refused, it may change the meaning */
    for (i = 0; i < b->len; i++) {
        for (k = 0; k < sizeof known / sizeof *known; k++) {
            if (strlen(known[k]) == b->key_len[i] && strcmp(known[k], b->keys[i]) == 0)
                break;
        }
        if (k == sizeof known / sizeof *known)
            return lfail(L, "qctm_gp.json: unknown field betm.%s", b->keys[i]);
    }
    if (get_num(L, b, "cp_fwd", NAN, &m->cp_fwd) || get_num(L, b, "cp_rev", NAN, &m->cp_rev)
        || get_num(L, b, "c_n", NAN, &m->c_n) || get_num(L, b, "i_0", NAN, &m->i_0)
        || get_num(L, b, "ci_fwd", NAN, &m->ci_fwd) || get_num(L, b, "ci_rev", NAN, &m->ci_rev)
        || get_num(L, b, "sigma_n", NAN, &m->sigma_n)
        || get_num(L, b, "sigma_i", NAN, &m->sigma_i) || get_num(L, b, "u0", 0.0, &m->u0)
        || get_num(L, b, "sigma0", 1e3, &m->sigma0) || get_num(L, b, "gamma", 3.0, &m->gamma))
        return -1;
    /* level-dependent stds: knots in |f_n|, used only when level_n is non-empty */
    if (jget(b, "level_n") == NULL)
        return 0;
    if (get_vec(L, jget(b, "level_n"), "betm.level_n", &m->level_n, &m->n_level) != 0)
        return -1;
    if (m->n_level == 0)
        return 0;
    if (get_vec(L, jget(b, "sigma_n_level"), "betm.sigma_n_level", &m->sigma_n_level, &n1) != 0
        || get_vec(L, jget(b, "sigma_i_level"), "betm.sigma_i_level", &m->sigma_i_level, &n2) != 0)
        return -1;
    if (n1 != m->n_level || n2 != m->n_level)
        return lfail(L, "qctm_gp.json: %s must have as many values as betm.level_n",
                     "betm.sigma_n_level and betm.sigma_i_level");
    return 0;
}

static int load_features(loader *L, qctm_model *m, const jval *doc)
{
    const jval *f = jget(doc, "features"), *w, *lead_v;
    long long lead = 0;
    m->window = 1;
    if (f != NULL && f->type != J_OBJ)
        return lfail(L, "qctm_gp.json: %s must be an object", "features");
    w = jget(f, "window_blocks");
    lead_v = jget(f, "lead_blocks"); /* absent or null: centred */
    if (lead_v != NULL && lead_v->type == J_NULL)
        lead_v = NULL;
    if ((w != NULL && get_int(L, w, "features.window_blocks", &m->window) != 0)
        || (lead_v != NULL && get_int(L, lead_v, "features.lead_blocks", &lead) != 0))
        return -1;
    /* window_mean (used when window > 1): half_hi = window // 2, or lead clipped to
     * [0, window - 1] */
    if (lead_v == NULL)
        m->half_hi = m->window / 2;
    else
        m->half_hi = lead < 0 ? 0 : (lead > m->window - 1 ? m->window - 1 : lead);
    m->half_lo = m->window - 1 - m->half_hi;
    return 0;
}

static int load_gp(loader *L, qctm_model *m, const jval *doc)
{
    const jval *g = jget(doc, "gp"), *a_n;
    size_t j;
    if (g == NULL || g->type != J_OBJ)
        return lfail(L, "qctm_gp.json: %s must be an object", "gp");
    if (get_num(L, g, "signal_var", NAN, &m->signal_var)
        || get_num(L, g, "noise_var", NAN, &m->noise_var)
        || get_num(L, g, "y_mean", NAN, &m->y_mean) || get_num(L, g, "y_std", NAN, &m->y_std)
        || get_num(L, g, "beta", 0.0, &m->beta) || get_num(L, g, "gate_z0", 0.0, &m->gate_z0)
        || get_num(L, g, "gate_s", 0.0, &m->gate_s))
        return -1;
    if (check_range(L, m->y_mean, -MAX_MODEL_VALUE, "gp.y_mean")
        || check_range(L, m->y_std, MIN_MODEL_SCALE, "gp.y_std")
        || check_range(L, m->signal_var, 0.0, "gp.signal_var")
        || check_range(L, m->noise_var, 0.0, "gp.noise_var")
        || check_range(L, m->beta, -MAX_MODEL_VALUE, "gp.beta")
        || check_range(L, m->gate_z0, -MAX_MODEL_VALUE, "gp.gate_z0")
        || check_range(L, m->gate_s, -MAX_MODEL_VALUE, "gp.gate_s"))
        return -1;
    m->has_signal = 1;
    if (m->version >= 6) { /* gp.signal false: signal_var 0, the kernel terms are 0 */
        static const char *const arrays[] = {"alpha", "a_n", "weights", "variance_file"};
        const jval *sig = jget(g, "signal");
        size_t k;
        if (sig == NULL || (sig->type != J_TRUE && sig->type != J_FALSE))
            return lfail(L, "qctm_gp.json: %s must be true or false", "gp.signal");
        m->has_signal = sig->type == J_TRUE;
        if (!m->has_signal) {
            for (k = 0; k < sizeof arrays / sizeof *arrays; k++)
                if (jget(g, arrays[k]) != NULL)
                    return lfail(L, "qctm_gp.json: gp.signal is false but gp.%s is present",
                                 arrays[k]);
            if (m->signal_var != 0.0)
                return lfail(L, "qctm_gp.json: %s", "gp.signal is false but gp.signal_var "
                             "is not 0");
            return get_rows(L, g, "gp", &m->gp); /* the domain's training rows */
        }
        if (jget(g, "alpha") == NULL)
            return lfail(L, "qctm_gp.json: %s", "gp.signal is true but gp.alpha is missing");
    }
    /* mean weights a_n = y_std signal_var alpha (computed from alpha if a file lacks a_n) */
    a_n = jget(g, "a_n");
    if (get_kernel(L, g, "gp", a_n != NULL ? "a_n" : "alpha", &m->gp) != 0)
        return -1;
    for (j = 0; j < m->gp.n; j++) {
        if (!(fabs(m->gp.w[j]) <= MAX_KERNEL_WEIGHT))
            return lfail(L, "qctm_gp.json: %s must be finite and within -1e12..1e12",
                         a_n != NULL ? "gp.a_n" : "gp.alpha");
        if (a_n == NULL)
            m->gp.w[j] = m->y_std * m->signal_var * m->gp.w[j];
    }
    return 0;
}

/* The missed-ventilation table (format 7, LogNoise.missed_lower): both arrays absent, or as
 * many finite values, the speeds strictly increasing and the widths >= 0. */
static int load_missed(loader *L, qctm_model *m, const jval *nz)
{
    const jval *k = jget(nz, "missed_speed_rpm"), *v = jget(nz, "missed_lower_n");
    size_t i, n;
    if (k == NULL && v == NULL)
        return 0;
    if (get_vec(L, k, "noise.missed_speed_rpm", &m->missed_rpm, &m->n_missed) != 0
        || get_vec(L, v, "noise.missed_lower_n", &m->missed_lower, &n) != 0)
        return -1;
    if (n != m->n_missed || n == 0)
        return lfail(L, "qctm_gp.json: %s must have as many values as noise.missed_speed_rpm",
                     "noise.missed_lower_n");
    for (i = 0; i < n; i++) {
        if (!isfinite(m->missed_rpm[i]) || !isfinite(m->missed_lower[i])
            || m->missed_lower[i] < 0.0 || (i > 0 && !(m->missed_rpm[i] > m->missed_rpm[i - 1])))
            return lfail(L, "qctm_gp.json: %s must be finite, the speeds strictly increasing "
                         "and the widths >= 0", "noise.missed_speed_rpm / missed_lower_n");
    }
    return 0;
}

static int load_noise(loader *L, qctm_model *m, const jval *doc)
{
    const jval *nz = jget(doc, "noise"), *ev;
    if (nz == NULL || nz->type == J_NULL)
        return 0;
    if (nz->type != J_OBJ)
        return lfail(L, "qctm_gp.json: %s must be an object or null", "noise");
    m->has_noise = 1;
    if (get_num(L, nz, "signal_var", NAN, &m->noise_signal_var)
        || get_num(L, nz, "log_mean", NAN, &m->log_mean)
        || get_num(L, nz, "log_bias", 1.2703628454614782, &m->log_bias)
        || get_num(L, nz, "gate_z0", 0.0, &m->noise_gate_z0)
        || get_num(L, nz, "gate_s", 0.0, &m->noise_gate_s))
        return -1;
    /* a separate bias where the shortfall says "ventilating" (format 5; null: one bias) */
    ev = jget(nz, "log_bias_event");
    if (ev != NULL && ev->type != J_NULL) {
        m->has_bias_event = 1;
        if (get_num(L, nz, "log_bias_event", NAN, &m->log_bias_event))
            return -1;
    }
    /* log-variance levels: finite and within +-100 (MAX_LOG_LEVEL in qctm.py) */
    if (!(fabs(m->log_mean) <= 100.0))
        return lfail(L, "qctm_gp.json: noise.%s is not a finite log variance within +-100", "log_mean");
    if (!(fabs(m->log_bias) <= 100.0))
        return lfail(L, "qctm_gp.json: noise.%s is not a finite log variance within +-100", "log_bias");
    if (m->has_bias_event && !(fabs(m->log_bias_event) <= 100.0))
        return lfail(L, "qctm_gp.json: noise.%s is not a finite log variance within +-100",
                     "log_bias_event");
    if (load_missed(L, m, nz) != 0)
        return -1;
    if (!isfinite(m->noise_gate_z0) || !isfinite(m->noise_gate_s))
        return lfail(L, "qctm_gp.json: %s", "noise.gate_z0 and noise.gate_s must be finite");
    if (!(m->noise_signal_var >= 0.0 && m->noise_signal_var <= 1e3))
        return lfail(L, "qctm_gp.json: %s", "noise.signal_var must be within 0..1000 "
                     "(MAX_NOISE_SIGNAL_VAR in qctm.py)");
    if (get_kernel(L, nz, "noise", "alpha", &m->noise) != 0)
        return -1;
    return check_noise_kernel(L, &m->noise);
}

/* Bounds.from_dict / Domain.from_dict: absent, null or {} give the defaults / no domain. */
static int load_limits(loader *L, qctm_model *m, const jval *doc)
{
    const jval *b = jget(doc, "bounds"), *d = jget(doc, "domain"), *v;
    size_t i, k;
    m->short_lo = -0.2;
    m->short_hi = 0.3;
    m->above_n = INFINITY;
    if (b != NULL && b->type != J_NULL && !(b->type == J_OBJ && b->len == 0)) {
        if (b->type != J_OBJ)
            return lfail(L, "qctm_gp.json: %s must be an object or null", "bounds");
        if ((v = jget(b, "shortfall")) != NULL) {
            if (v->type != J_ARR || v->len != 2 || v->items[0].type != J_NUM
                || v->items[1].type != J_NUM)
                return lfail(L, "qctm_gp.json: %s must be [lo, hi]", "bounds.shortfall");
            m->short_lo = v->items[0].num;
            m->short_hi = v->items[1].num;
        }
        v = jget(b, "above_n"); /* null: no upper clamp (JSON has no infinity) */
        if (v != NULL && v->type != J_NULL && get_num(L, b, "above_n", INFINITY, &m->above_n))
            return -1;
    }
    if (d == NULL || d->type == J_NULL || (d->type == J_OBJ && d->len == 0))
        return 0;
    if (d->type != J_OBJ)
        return lfail(L, "qctm_gp.json: %s must be an object or null", "domain");
    m->has_domain = 1;
    if (get_num(L, d, "max_distance", 1.0, &m->max_distance) != 0)
        return -1;
    v = jget(d, "ranges");
    if (v == NULL || v->type != J_OBJ)
        return lfail(L, "qctm_gp.json: %s must be an object", "domain.ranges");
    for (i = 0; i < v->len; i++) {
        const jval *r = &v->items[i];
        for (k = 0; k < 4; k++) {
            if (strlen(DOMAIN_INPUTS[k]) == v->key_len[i] && strcmp(DOMAIN_INPUTS[k], v->keys[i]) == 0)
                break;
        }
        if (k == 4)
            return lfail(L, "qctm_gp.json: unknown input domain.ranges.%s", v->keys[i]);
        if (r->type != J_ARR || r->len < 2 || r->items[0].type != J_NUM
            || r->items[1].type != J_NUM)
            return lfail(L, "qctm_gp.json: domain.ranges.%s must be [lo, hi]", v->keys[i]);
        m->has_range[k] = 1; /* a repeated key: the last one wins, as in Python */
        m->range_lo[k] = r->items[0].num;
        m->range_hi[k] = r->items[1].num;
    }
    return 0;
}

static int load_document(loader *L, qctm_model *m, const jval *doc)
{
    const jval *v;
    long long version = 1;
    if (doc->type != J_OBJ)
        return lfail(L, "qctm_gp.json: %s", "the document must be a JSON object");
    v = jget(doc, "format");
    if (v == NULL || v->type != J_STR || strcmp(v->str, "rigtool-qctm-gp") != 0)
        return lfail(L, "qctm_gp.json: %s", "not a rigtool-qctm-gp document");
    if ((v = jget(doc, "format_version")) != NULL
        && get_int(L, v, "format_version", &version) != 0)
        return -1;
    if (version < 2)
        return lfail(L, "qctm_gp.json: %s", "a version-1 model on raw (n, I, h) inputs: rerun "
                     "rigtool calibrate to refit it");
    if (version > 7)
        return lfail(L, "qctm_gp.json: %s", "format version above 7: this evaluator reads 2-7");
    m->version = (int)version;
    v = jget(doc, "intervals_validated");
    if (v != NULL && v->type != J_TRUE && v->type != J_FALSE)
        return lfail(L, "qctm_gp.json: %s must be true or false", "intervals_validated");
    m->intervals_validated = v == NULL ? -1 : v->type == J_TRUE;
    return load_betm(L, m, jget(doc, "betm")) || load_features(L, m, doc)
           || load_gp(L, m, doc) || load_noise(L, m, doc) || load_limits(L, m, doc);
}

void qctm_free(qctm_model *m)
{
    if (m == NULL)
        return;
    free(m->level_n);
    free(m->sigma_n_level);
    free(m->sigma_i_level);
    free(m->gp.xt);
    free(m->gp.w);
    free(m->noise.xt);
    free(m->noise.w);
    free(m->missed_rpm);
    free(m->missed_lower);
    free(m->kinv);
    free(m);
}

int qctm_has_kinv(const qctm_model *m)
{
    return m->kinv != NULL;
}

int qctm_intervals_validated(const qctm_model *m)
{
    return m->intervals_validated;
}

qctm_model *qctm_load(const char *path, char *err, size_t errlen)
{
    size_t plen = strlen(path), dlen, size;
    int is_json = plen >= 5 && strcmp(path + plen - 5, ".json") == 0, missing;
    char *json_path, *text, *kinv_path;
    const char *sep, *vfile = "qctm_gp_kinv.npy";
    const jval *vf;
    qctm_model *m;
    jval doc;
    loader L;
    L.err = err;
    L.errlen = errlen;
    /* folder of the model: the path itself, or the .json file's directory */
    if (is_json) {
        const char *s1 = strrchr(path, '/'), *s2 = strrchr(path, '\\');
        sep = s1 > s2 ? s1 : s2;
        dlen = sep == NULL ? 0 : (size_t)(sep - path) + 1;
    } else {
        dlen = plen + (plen > 0 && path[plen - 1] != '/' ? 1 : 0);
    }
    json_path = malloc(plen + 32);
    if (json_path == NULL) {
        set_err(err, errlen, "out of memory");
        return NULL;
    }
    if (is_json) {
        strcpy(json_path, path);
    } else {
        memcpy(json_path, path, plen);
        if (dlen > plen)
            json_path[plen] = '/';
        strcpy(json_path + dlen, "qctm_gp.json");
    }
    text = read_file(json_path, &size, &missing, err, errlen);
    if (text == NULL) {
        free(json_path);
        return NULL;
    }
    m = calloc(1, sizeof *m);
    if (m == NULL) {
        set_err(err, errlen, "out of memory");
        free(text);
        free(json_path);
        return NULL;
    }
    if (jparse(text, size, &doc, err, errlen) != 0) {
        /* prefix the file name to the parser's "line L, column C: ..." */
        char msg[256];
        snprintf(msg, sizeof msg, "%s", err != NULL && errlen > 0 ? err : "");
        set_err(err, errlen, "%s: %s", json_path, msg);
        free(text);
        free(json_path);
        qctm_free(m);
        return NULL;
    }
    free(text);
    if (load_document(&L, m, &doc) != 0) {
        jfree(&doc);
        free(json_path);
        qctm_free(m);
        return NULL;
    }
    /* posterior variance: gp.variance_file relative to the folder (or absolute) */
    vf = jget(jget(&doc, "gp"), "variance_file");
    if (vf != NULL && vf->type == J_STR)
        vfile = vf->str;
    kinv_path = malloc(dlen + strlen(vfile) + 1);
    if (kinv_path == NULL) {
        set_err(err, errlen, "out of memory");
        jfree(&doc);
        free(json_path);
        qctm_free(m);
        return NULL;
    }
    if (vfile[0] == '/') {
        strcpy(kinv_path, vfile);
    } else {
        memcpy(kinv_path, json_path, dlen);
        strcpy(kinv_path + dlen, vfile);
    }
    jfree(&doc);
    free(json_path);
    if (!m->has_signal) { /* nothing uses a posterior-variance matrix: one is another fit's */
        FILE *f = fopen(kinv_path, "rb");
        if (f != NULL) {
            fclose(f);
            set_err(err, errlen, "%s is present but the model has no GP signal (gp.signal "
                    "false): the file belongs to another fit", kinv_path);
            free(kinv_path);
            qctm_free(m);
            return NULL;
        }
        free(kinv_path);
        return m;
    }
    if (read_npy(kinv_path, m->gp.n, &m->kinv, &missing, err, errlen) != 0) {
        if (missing && m->version >= 6)
            set_err(err, errlen, "%s is missing but the model has a GP signal (gp.signal "
                    "true)", kinv_path);
        if (!missing || m->version >= 6) {
            free(kinv_path);
            qctm_free(m);
            return NULL;
        }
        m->kinv = NULL; /* no file: the prior variance, as rigtool.models */
        if (err != NULL && errlen > 0)
            err[0] = '\0';
    }
    free(kinv_path);
    return m;
}

/* ---------------------------------------------------------------- 4. evaluation */

/* numpy's NaN-propagating minimum and maximum */
static double np_min(double a, double b)
{
    return (a <= b || isnan(a)) ? a : b;
}

static double np_max(double a, double b)
{
    return (a >= b || isnan(a)) ? a : b;
}

/* numpy.clip(x, lo, hi) = minimum(maximum(x, lo), hi) */
static double np_clip(double x, double lo, double hi)
{
    return np_min(np_max(x, lo), hi);
}

static double np_sign(double x)
{
    return x > 0 ? 1.0 : (x < 0 ? -1.0 : (x == 0 ? 0.0 : x));
}

/* numpy.interp(x, xp, fp): linear, clamped to fp[0] / fp[-1] outside the knots */
static double np_interp(double x, const double *xp, const double *fp, size_t n)
{
    size_t lo = 0, hi = n, j;
    double slope, r;
    if (n == 1)
        return fp[0]; /* numpy: left, right and the knot all give fp[0], NaN too */
    if (isnan(x))
        return x;
    if (x < xp[0])
        return fp[0];
    if (x > xp[n - 1])
        return fp[n - 1];
    while (lo < hi) { /* j = last knot with xp[j] <= x */
        size_t mid = lo + (hi - lo) / 2;
        if (x >= xp[mid])
            lo = mid + 1;
        else
            hi = mid;
    }
    j = lo - 1;
    if (j == n - 1 || xp[j] == x)
        return fp[j];
    slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j]);
    r = slope * (x - xp[j]) + fp[j];
    if (isnan(r)) { /* numpy: if we get NaN in one direction, try the other */
        r = slope * (x - xp[j + 1]) + fp[j + 1];
        if (isnan(r) && fp[j] == fp[j + 1])
            r = fp[j];
    }
    return r;
}

/* f_n = C_p |n| n, forward or reverse coefficient */
static double speed_estimate(const qctm_model *m, double n)
{
    return (n >= 0 ? m->cp_fwd : m->cp_rev) * fabs(n) * n;
}

/* shortfall = 1 - |I| / (C_n |n|^3 + I_0), 0 where the expected current is not positive
 * (also for a NaN speed) */
static double shortfall(const qctm_model *m, double n, double i)
{
    double i_hat = m->c_n * pow(fabs(n), 3.0) + m->i_0;
    return i_hat > 0 ? 1.0 - fabs(i) / i_hat : 0.0;
}

/* (sigma_n^2, sigma_i^2) at thrust level f: interpolated in |f| when the tables exist */
static void betm_variances(const qctm_model *m, double f, double *var_n, double *var_i)
{
    double a = fabs(f), s;
    if (m->n_level == 0) {
        *var_n = m->sigma_n * m->sigma_n;
        *var_i = m->sigma_i * m->sigma_i;
        return;
    }
    s = np_interp(a, m->level_n, m->sigma_n_level, m->n_level);
    *var_n = s * s;
    s = np_interp(a, m->level_n, m->sigma_i_level, m->n_level);
    *var_i = s * s;
}

/* Betm.fuse: inverse-variance mean of f_n, f_i and the prior; f_i is dropped when
 * |f_n - f_i| / sqrt(var_n + var_i) > gamma or when it is NaN (no current) */
static double betm_fuse(const qctm_model *m, double n, double i, double *f_n_out)
{
    double f_n = speed_estimate(m, n), s = np_sign(n), d, f_i, var_n, var_i, w_n, w_i, w_0;
    int ok;
    d = np_max(fabs(i) - m->i_0, 0.0); /* |I| - I_0 clamped at 0 */
    f_i = s * (s >= 0 ? m->ci_fwd : m->ci_rev) * pow(d, 2.0 / 3.0);
    betm_variances(m, f_n, &var_n, &var_i);
    d = fabs(f_n - f_i) / sqrt(var_n + var_i);
    ok = isfinite(f_i) && d <= m->gamma;
    w_n = 1.0 / var_n;
    w_0 = 1.0 / (m->sigma0 * m->sigma0);
    w_i = ok ? 1.0 / var_i : 0.0;
    *f_n_out = f_n;
    return (f_n * w_n + (ok ? f_i : 0.0) * w_i + m->u0 * w_0) / (w_n + w_i + w_0);
}

/* Matern-5/2 correlation m(r) = (1 + sqrt5 r + 5 r^2 / 3) exp(-sqrt5 r) of the standardised
 * input xs and training row j of ks */
static double matern(const kernel_sum *ks, const double xs[3], size_t j)
{
    const double *t = ks->xt + 3 * j;
    double d0 = (xs[0] - t[0]) / ks->ls[0], d1 = (xs[1] - t[1]) / ks->ls[1],
           d2 = (xs[2] - t[2]) / ks->ls[2];
    double s = SQRT5 * sqrt(d0 * d0 + d1 * d1 + d2 * d2);
    return (1.0 + s + s * s / 3.0) * exp(-s);
}

static void standardise(const kernel_sum *ks, const double x[3], double xs[3])
{
    int k;
    for (k = 0; k < 3; k++)
        xs[k] = (x[k] - ks->x_mean[k]) / ks->x_scale[k];
}

/* Noise variance of a new measurement (N^2): exp(log_mean + bias(z) + sum_j k'_j alpha_j),
 * bias(z) = log_bias + (log_bias_event - log_bias) / (1 + exp(-(|z| - gate_z0) / gate_s))
 * with the noise's own gate (gate_s <= 0: gate 0), or log_bias when there is no event bias. */
static double noise_var_n2(const qctm_model *m, const double x[3])
{
    double xs[3], sum = 0.0, bias = m->log_bias;
    size_t j;
    standardise(&m->noise, x, xs);
    for (j = 0; j < m->noise.n; j++)
        sum += m->noise_signal_var * matern(&m->noise, xs, j) * m->noise.w[j];
    if (m->has_bias_event && m->noise_gate_s > 0.0) {
        double u = np_clip((fabs(x[1]) - m->noise_gate_z0) / m->noise_gate_s, -700.0, 700.0);
        bias += (m->log_bias_event - m->log_bias) / (1.0 + exp(-u));
    }
    return exp(m->log_mean + bias + sum);
}

/* ThrustModel.correction: GP mean of f_measured - f_BETM and the std of a new measurement.
 * k (n values) is scratch space. */
static void correction(const qctm_model *m, const double x[3], double *k, double *mean,
                       double *std)
{
    double xs[3], g, u, sum = 0.0, var = m->signal_var, var_n2;
    size_t j, l;
    standardise(&m->gp, x, xs);
    for (j = 0; m->has_signal && j < m->gp.n; j++) {
        double c = matern(&m->gp, xs, j);
        k[j] = m->signal_var * c;
        sum += m->gp.w[j] * c;
    }
    /* gated mean term g(z) = beta z / (1 + exp(-(|z| - z0) / s)); s <= 0: beta z */
    if (m->gate_s <= 0.0) {
        g = m->beta * x[1];
    } else {
        u = np_clip((fabs(x[1]) - m->gate_z0) / m->gate_s, -700.0, 700.0);
        g = m->beta * x[1] / (1.0 + exp(-u));
    }
    *mean = m->y_mean + g + sum;
    if (m->kinv != NULL) { /* posterior: signal_var - k^T Kinv k */
        double q = 0.0;
        for (j = 0; j < m->gp.n; j++) {
            const double *row = m->kinv + j * m->gp.n;
            double r = 0.0;
            for (l = 0; l < m->gp.n; l++)
                r += row[l] * k[l];
            q += k[j] * r;
        }
        var -= q;
    }
    var_n2 = m->y_std * m->y_std * (np_max(var, 0.0) + m->noise_var);
    if (m->has_noise)
        var_n2 += noise_var_n2(m, x);
    *std = sqrt(var_n2);
}

/* Std of a new measurement under the GP prior (no training data), N */
static double prior_std(const qctm_model *m, const double x[3])
{
    double var = m->y_std * m->y_std * (m->signal_var + m->noise_var);
    if (m->has_noise)
        var += noise_var_n2(m, x);
    return sqrt(var);
}

/* Distance of x to the nearest training row, standardised by gp.x_mean, gp.x_scale */
static double nearest_distance(const qctm_model *m, const double x[3])
{
    double xs[3], best = INFINITY;
    size_t j;
    standardise(&m->gp, x, xs);
    for (j = 0; j < m->gp.n; j++) {
        const double *t = m->gp.xt + 3 * j;
        double d0 = xs[0] - t[0], d1 = xs[1] - t[1], d2 = xs[2] - t[2];
        double s = d0 * d0 + d1 * d1 + d2 * d2;
        best = np_min(best, s);
    }
    return sqrt(best);
}

/* window_mean: mean shortfall of the valid blocks in a window of `window` blocks reaching
 * half_hi ahead, truncated at the ends of [a, b) (a segment); 0 where the window has none.
 * Prefix sums as numpy.cumsum, so the rounding is the same. */
static void window_mean(const qctm_model *m, const double *vals, const int *ok, size_t a,
                        size_t b, double *c, long long *cnt, double *out)
{
    size_t len = b - a, j;
    if (m->window <= 1) {
        for (j = a; j < b; j++)
            out[j] = ok[j] ? vals[j] : 0.0;
        return;
    }
    c[0] = 0.0;
    cnt[0] = 0;
    for (j = 0; j < len; j++) {
        c[j + 1] = c[j] + vals[a + j];
        cnt[j + 1] = cnt[j] + (ok[a + j] != 0);
    }
    for (j = 0; j < len; j++) {
        long long lo = (long long)j - m->half_lo, hi = (long long)j + m->half_hi + 1, count;
        if (lo < 0)
            lo = 0;
        if (hi > (long long)len)
            hi = (long long)len;
        count = cnt[hi] - cnt[lo];
        out[a + j] = count > 0 ? (c[hi] - c[lo]) / (double)count : 0.0;
    }
}

int qctm_evaluate(const qctm_model *m, size_t count, const double *speed_rpm,
                  const double *current_a, const double *depth_m, const long *segment,
                  double *thrust_n, double *lo95, double *hi95, int *flags, double *distance,
                  char *err, size_t errlen)
{
    double *vals = malloc((count + 1) * sizeof *vals), *c = malloc((count + 1) * sizeof *c);
    double *shortw = malloc((count + 1) * sizeof *shortw), *k = malloc(m->gp.n * sizeof *k);
    long long *cnt = malloc((count + 1) * sizeof *cnt);
    int *ok = malloc((count + 1) * sizeof *ok), *wok = malloc((count + 1) * sizeof *wok);
    size_t t, a;
    int rc = 0;
    if (!vals || !c || !shortw || !k || !cnt || !ok || !wok) {
        set_err(err, errlen, "out of memory for %lu blocks", (unsigned long)count);
        rc = -1;
        goto done;
    }
    /* current fault: shortfall outside bounds.shortfall, or a non-finite current */
    for (t = 0; t < count; t++) {
        double s = shortfall(m, speed_rpm[t], current_a[t]);
        ok[t] = isfinite(current_a[t]) && s >= m->short_lo && s <= m->short_hi;
        /* a block without a speed reading has no shortfall either: not in any window */
        vals[t] = ok[t] && isfinite(speed_rpm[t]) ? s : 0.0;
        wok[t] = ok[t] && isfinite(speed_rpm[t]);
    }
    /* shortfall window within each run of equal segment labels, faults left out */
    for (a = 0; a < count;) {
        size_t b = a + 1;
        while (b < count && (segment == NULL || segment[b] == segment[a]))
            b++;
        window_mean(m, vals, wok, a, b, c, cnt, shortw);
        a = b;
    }
    for (t = 0; t < count; t++) {
        double n = speed_rpm[t], i = current_a[t], h = depth_m[t];
        double x[3], xsafe[3], f_n, f_b, mean, std, raw, lo_b, hi_b, th, lo, hi, dist = INFINITY;
        double wide, var_n, var_i, sd_n, nan_or_0;
        int good, out = 0, fl = 0, fault = !ok[t], q;
        x[0] = n;
        x[1] = speed_estimate(m, n) * shortw[t]; /* z (N) */
        x[2] = h;
        good = isfinite(x[0]) && isfinite(x[1]) && isfinite(x[2]);
        for (q = 0; q < 3; q++)
            xsafe[q] = good ? x[q] : m->gp.x_mean[q];
        f_b = betm_fuse(m, n, fault ? NAN : i, &f_n);
        correction(m, xsafe, k, &mean, &std);
        raw = f_b + mean;
        /* physics: between 0 and f_BETM + above_n, in the direction the propeller turns */
        lo_b = f_n >= 0 ? 0.0 : np_min(0.0, f_b - m->above_n); /* false for NaN: reverse */
        hi_b = f_n >= 0 ? np_max(0.0, f_b + m->above_n) : 0.0;
        th = np_clip(raw, lo_b, hi_b);
        if (isfinite(raw) && th != raw)
            fl |= QCTM_CLAMPED;
        lo = th - QCTM_Z95 * std;
        hi = th + QCTM_Z95 * std;
        if (m->n_missed > 0) { /* ventilation the shortfall misses: the loss side only */
            double miss = np_interp(fabs(xsafe[0]), m->missed_rpm, m->missed_lower, m->n_missed);
            if (m->noise_gate_s > 0.0)
                miss *= 1.0 - 1.0 / (1.0 + exp(-np_clip((fabs(xsafe[1]) - m->noise_gate_z0)
                                                        / m->noise_gate_s, -700.0, 700.0)));
            if (f_n >= 0)
                lo -= miss;
            else
                hi += miss;
        }
        /* outside the training domain: widen to [0, f_BETM] +- the prior noise */
        if (m->has_domain) {
            const double v[4] = {n, fabs(i), h, x[1]};
            if (good)
                dist = nearest_distance(m, x);
            for (q = 0; q < 4; q++)
                if (m->has_range[q] && !(v[q] >= m->range_lo[q] && v[q] <= m->range_hi[q]))
                    out = 1;
            if (!(dist <= m->max_distance))
                out = 1;
        } else {
            out = !good;
        }
        if (out) {
            wide = QCTM_Z95 * prior_std(m, xsafe);
            lo = np_min(lo, np_min(0.0, f_b) - wide);
            hi = np_max(hi, np_max(0.0, f_b) + wide);
            fl |= QCTM_OUT_OF_DOMAIN;
        }
        /* current fault: the speed estimate, anywhere between no loss and total loss */
        if (fault) {
            betm_variances(m, f_n, &var_n, &var_i);
            sd_n = sqrt(var_n);
            th = f_n;
            lo = np_min(np_min(0.0, f_n) - QCTM_Z95 * sd_n, lo);
            hi = np_max(np_max(0.0, f_n) + QCTM_Z95 * sd_n, hi);
            fl |= QCTM_CURRENT_FAULT;
        }
        /* no speed or depth: no thrust (adding 0.0 turns -0 into 0, as in Python) */
        nan_or_0 = (isfinite(n) && isfinite(h)) ? 0.0 : NAN;
        thrust_n[t] = th + nan_or_0;
        lo95[t] = lo + nan_or_0;
        hi95[t] = hi + nan_or_0;
        flags[t] = fl;
        if (distance != NULL)
            distance[t] = dist;
    }
done:
    free(vals);
    free(c);
    free(shortw);
    free(k);
    free(cnt);
    free(ok);
    free(wok);
    return rc;
}
