/* qctm_eval: evaluate an exported QCTM-GP thrust model on block means read from stdin.
 *
 * Build:  cc -std=c99 -O2 -o qctm_eval qctm_gp.c qctm_eval_main.c -lm
 * Use:    qctm_eval CALIBRATION_DIR|qctm_gp.json < blocks.csv > thrust.csv
 *
 * Input: one line per consecutive block mean (features.block_s, 0.2 s) of a record,
 *     speed_rpm,current_a,depth_m,segment
 * `segment` is a label (e.g. the point index), compared as text: a new segment starts
 * where it changes (the shortfall window is truncated there); it may be left out (one
 * segment). An empty number field is NaN (no reading). Blank lines, lines starting with
 * '#' and a first line starting with "speed_rpm" (a header) are skipped.
 * Output: one line per block, thrust_n,lo95,hi95,flags (%.17g; flags: 1 out of domain,
 * 2 current fault, 4 clamped). All of stdin is read first: a centred window looks ahead.
 * Exit status: 0 done, 1 the model cannot be loaded, 2 bad usage or input.
 */
#include "qctm_gp.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef struct {
    size_t n, cap;
    double *speed, *current, *depth;
    long *segment;
} blocks;

/* Read one line of any length into *buf (without the newline); 0 at end of input. */
static int read_line(FILE *f, char **buf, size_t *cap)
{
    size_t n = 0;
    int c;
    while ((c = fgetc(f)) != EOF && c != '\n') {
        if (n + 1 >= *cap) {
            size_t nc = *cap ? 2 * *cap : 256;
            char *nb = realloc(*buf, nc);
            if (nb == NULL)
                return -1;
            *buf = nb;
            *cap = nc;
        }
        (*buf)[n++] = (char)c;
    }
    if (c == EOF && n == 0)
        return 0;
    if (*cap == 0 && (*buf = malloc(*cap = 1)) == NULL)
        return -1;
    (*buf)[n] = '\0';
    return 1;
}

/* Strip spaces, tabs and a carriage return around a field, in place. */
static char *trim(char *s)
{
    char *e;
    while (*s == ' ' || *s == '\t')
        s++;
    e = s + strlen(s);
    while (e > s && (e[-1] == ' ' || e[-1] == '\t' || e[-1] == '\r'))
        *--e = '\0';
    return s;
}

/* A number field: the whole field must be a number (strtod: also nan, inf); empty = NaN. */
static int parse_num(const char *s, double *out)
{
    char *end;
    if (*s == '\0') {
        *out = strtod("nan", NULL);
        return 0;
    }
    *out = strtod(s, &end);
    return *end == '\0' ? 0 : -1;
}

static int push(blocks *b, double n, double i, double h, long seg)
{
    if (b->n == b->cap) {
        size_t nc = b->cap ? 2 * b->cap : 1024;
        double *s = realloc(b->speed, nc * sizeof *s), *c, *d;
        long *g;
        if (s == NULL)
            return -1;
        b->speed = s;
        if ((c = realloc(b->current, nc * sizeof *c)) == NULL)
            return -1;
        b->current = c;
        if ((d = realloc(b->depth, nc * sizeof *d)) == NULL)
            return -1;
        b->depth = d;
        if ((g = realloc(b->segment, nc * sizeof *g)) == NULL)
            return -1;
        b->segment = g;
        b->cap = nc;
    }
    b->speed[b->n] = n;
    b->current[b->n] = i;
    b->depth[b->n] = h;
    b->segment[b->n] = seg;
    b->n++;
    return 0;
}

int main(int argc, char **argv)
{
    char err[512] = "", *line = NULL, *prev_label = NULL;
    size_t cap = 0, lineno = 0, t;
    long seg = 0;
    blocks b = {0, 0, NULL, NULL, NULL, NULL};
    double *out;
    int *flags, r, status = 0;
    qctm_model *m;
    if (argc != 2 || strcmp(argv[1], "-h") == 0 || strcmp(argv[1], "--help") == 0) {
        fprintf(stderr, "usage: %s CALIBRATION_DIR|qctm_gp.json < blocks.csv\n"
                        "  stdin:  speed_rpm,current_a,depth_m,segment per block\n"
                        "  stdout: thrust_n,lo95,hi95,flags per block\n",
                argc > 0 ? argv[0] : "qctm_eval");
        return 2;
    }
    m = qctm_load(argv[1], err, sizeof err);
    if (m == NULL) {
        fprintf(stderr, "qctm_eval: %s\n", err);
        return 1;
    }
    if (qctm_intervals_validated(m) == 0)
        fprintf(stderr, "qctm_eval: note: trained on one run: its 95 %% intervals were not "
                        "validated on another run\n");
    while ((r = read_line(stdin, &line, &cap)) > 0) {
        char *f[5], *s = line;
        const char *label;
        int nf = 0;
        double v[3];
        lineno++;
        s = trim(s);
        if (*s == '\0' || *s == '#' || (b.n == 0 && strncmp(s, "speed_rpm", 9) == 0))
            continue;
        /* split at commas: 3 or 4 fields */
        f[nf++] = s;
        for (; *s != '\0'; s++) {
            if (*s == ',') {
                *s = '\0';
                if (nf == 5)
                    break;
                f[nf++] = s + 1;
            }
        }
        if (nf < 3 || nf > 4) {
            fprintf(stderr, "qctm_eval: stdin line %lu: expected speed_rpm,current_a,depth_m"
                            "[,segment]\n", (unsigned long)lineno);
            status = 2;
            break;
        }
        for (t = 0; t < 3; t++) {
            if (parse_num(trim(f[t]), &v[t]) != 0) {
                fprintf(stderr, "qctm_eval: stdin line %lu: field %lu is not a number\n",
                        (unsigned long)lineno, (unsigned long)t + 1);
                status = 2;
                break;
            }
        }
        if (status != 0)
            break;
        /* a new segment where the label changes */
        label = nf == 4 ? trim(f[3]) : "";
        if (prev_label != NULL && strcmp(prev_label, label) != 0)
            seg++;
        free(prev_label);
        prev_label = malloc(strlen(label) + 1);
        if (prev_label == NULL || push(&b, v[0], v[1], v[2], seg) != 0) {
            r = -1;
            break;
        }
        strcpy(prev_label, label);
    }
    free(line);
    free(prev_label);
    if (r < 0 && status == 0) {
        fprintf(stderr, "qctm_eval: out of memory reading stdin\n");
        status = 2;
    }
    out = malloc((3 * b.n + 1) * sizeof *out);
    flags = malloc((b.n + 1) * sizeof *flags);
    if (status == 0 && (out == NULL || flags == NULL)) {
        fprintf(stderr, "qctm_eval: out of memory for %lu blocks\n", (unsigned long)b.n);
        status = 2;
    }
    if (status == 0 && qctm_evaluate(m, b.n, b.speed, b.current, b.depth, b.segment, out,
                                     out + b.n, out + 2 * b.n, flags, NULL, err,
                                     sizeof err) != 0) {
        fprintf(stderr, "qctm_eval: %s\n", err);
        status = 2;
    }
    for (t = 0; status == 0 && t < b.n; t++)
        printf("%.17g,%.17g,%.17g,%d\n", out[t], out[b.n + t], out[2 * b.n + t], flags[t]);
    if (status == 0 && (fflush(stdout) != 0 || ferror(stdout))) {
        fprintf(stderr, "qctm_eval: cannot write stdout\n");
        status = 2;
    }
    free(out);
    free(flags);
    free(b.speed);
    free(b.current);
    free(b.depth);
    free(b.segment);
    qctm_free(m);
    return status;
}
