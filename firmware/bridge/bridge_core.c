/* rigtool bridge firmware 1.0: line parser, commands, range checks, watchdog, telemetry.
 *
 * Grammar (after trimming ASCII whitespace at both ends; one space between fields):
 *   SET <ch> <value> | PW <ch> <value> | GET <ch> | STOP | HB | PING
 * with <ch> = digits and <value> = [+-]digits. Every non-empty line gets one reply. */
#include "bridge_core.h"

#define NUM_BUF 24u  /* a uint64 in decimal, a sign and a NUL */

typedef struct {
    uint64_t mag;       /* saturates at UINT64_MAX */
    uint8_t negative;
} number;

typedef struct {
    const char *s;
    size_t n;
    size_t pos;
} cursor;

static int is_space(char c)
{
    /* Python's str.strip() set within ASCII: \t \n \v \f \r, 0x1c..0x1f and space */
    return c == ' ' || (c >= '\t' && c <= '\r') || (c >= 0x1c && c <= 0x1f);
}

static int is_digit(char c)
{
    return c >= '0' && c <= '9';
}

static void send(bridge *b, const char *text, size_t n)
{
    b->hooks.write(b->hooks.ctx, text, n);
}

static size_t str_len(const char *s)
{
    size_t n = 0;
    while (s[n] != '\0') {
        n++;
    }
    return n;
}

/* Append `src` to `dst` (capacity `cap`, NUL-terminated); returns the new length. */
static size_t append(char *dst, size_t len, size_t cap, const char *src)
{
    while (*src != '\0' && len + 1 < cap) {
        dst[len++] = *src++;
    }
    dst[len] = '\0';
    return len;
}

static void format_u64(char *out, uint64_t v)
{
    char tmp[NUM_BUF];
    size_t n = 0, i;
    do {
        tmp[n++] = (char)('0' + (int)(v % 10u));
        v /= 10u;
    } while (v != 0u);
    for (i = 0; i < n; i++) {
        out[i] = tmp[n - 1 - i];
    }
    out[n] = '\0';
}

static void reply(bridge *b, const char *head, const char *tail)
{
    char buf[BRIDGE_MAX_LINE + 32u];
    size_t len = append(buf, 0, sizeof buf - 1u, head);
    len = append(buf, len, sizeof buf - 1u, tail);
    buf[len++] = '\n';
    send(b, buf, len);
}

static void reply_value(bridge *b, uint32_t v)
{
    char num[NUM_BUF];
    format_u64(num, v);
    reply(b, "OK ", num);
}

static void reply_out_of_range(bridge *b)
{
    char num[NUM_BUF];
    char head[NUM_BUF + 24u];
    size_t len = append(head, 0, sizeof head, "ERR out of range ");
    format_u64(num, b->cfg.ccr_min);
    len = append(head, len, sizeof head, num);
    (void)append(head, len, sizeof head, "..");
    format_u64(num, b->cfg.ccr_max);
    reply(b, head, num);
}

/* Match the literal `word` at the cursor. */
static int take_word(cursor *c, const char *word)
{
    size_t n = str_len(word);
    size_t i;
    if (c->n - c->pos < n) {
        return 0;
    }
    for (i = 0; i < n; i++) {
        if (c->s[c->pos + i] != word[i]) {
            return 0;
        }
    }
    c->pos += n;
    return 1;
}

/* One or more digits; `*first` is where they start (for echoing a channel number). */
static int take_digits(cursor *c, number *out, size_t *first)
{
    size_t start = c->pos;
    out->mag = 0u;
    while (c->pos < c->n && is_digit(c->s[c->pos])) {
        unsigned d = (unsigned)(c->s[c->pos] - '0');
        out->mag = out->mag > (UINT64_MAX - d) / 10u ? UINT64_MAX : out->mag * 10u + d;
        c->pos++;
    }
    if (first != NULL) {
        *first = start;
    }
    return c->pos > start;
}

static int take_value(cursor *c, number *out)
{
    out->negative = 0u;
    if (c->pos < c->n && (c->s[c->pos] == '+' || c->s[c->pos] == '-')) {
        out->negative = c->s[c->pos] == '-';
        c->pos++;
    }
    return take_digits(c, out, NULL);
}

static int at_end(const cursor *c)
{
    return c->pos == c->n;
}

/* The whole line is `word` (the cursor is left where it was). */
static int is_exactly(const cursor *c, const char *word)
{
    cursor probe = *c;
    return take_word(&probe, word) && at_end(&probe);
}

/* "ERR no channel <n>": the digits as sent, leading zeros dropped, so any length works. */
static void reply_no_channel(bridge *b, const cursor *c, size_t first, size_t end)
{
    char num[BRIDGE_MAX_LINE + 1u];
    size_t n = 0;
    while (first + 1u < end && c->s[first] == '0') {
        first++;
    }
    while (first < end) {
        num[n++] = c->s[first++];
    }
    num[n] = '\0';
    reply(b, "ERR no channel ", num);
}

static void apply(bridge *b, uint8_t ch, uint32_t ccr)
{
    b->ccr[ch - 1u] = ccr;
    b->hooks.set_compare(b->hooks.ctx, ch, ccr);
}

void bridge_all_neutral(bridge *b)
{
    uint8_t ch;
    for (ch = 1u; ch <= b->cfg.channels; ch++) {
        apply(b, ch, b->cfg.neutral_ccr);
    }
}

/* Compare value for a pulse of `us` microseconds: us * f_TIM / (1e6 (PSC+1)), rounded to the
 * nearest count (halves to even). Returns 0 when it cannot be represented. */
static int pulse_to_ccr(const bridge_config *cfg, uint64_t us, uint64_t *ccr)
{
    uint64_t den = 1000000u * ((uint64_t)cfg->psc + 1u);
    uint64_t num, q, r;
    if (cfg->timer_clock_hz != 0u && us > UINT64_MAX / cfg->timer_clock_hz) {
        return 0;
    }
    num = us * cfg->timer_clock_hz;
    q = num / den;
    r = num % den;
    if (r > den - r || (r == den - r && (q & 1u) != 0u)) {
        q++;
    }
    *ccr = q;
    return 1;
}

/* SET / PW: check the channel, then the value, then apply it. */
static void command_output(bridge *b, int pulse, const cursor *c, const number *ch, size_t ch_first,
                           size_t ch_end, const number *value)
{
    uint64_t ccr = value->mag;
    if (ch->mag < 1u || ch->mag > b->cfg.channels) {
        reply_no_channel(b, c, ch_first, ch_end);
        return;
    }
    if (pulse && !pulse_to_ccr(&b->cfg, value->mag, &ccr)) {
        reply_out_of_range(b);
        return;
    }
    if ((value->negative && ccr != 0u) || ccr < b->cfg.ccr_min || ccr > b->cfg.ccr_max) {
        reply_out_of_range(b);
        return;
    }
    apply(b, (uint8_t)ch->mag, (uint32_t)ccr);
    reply_value(b, (uint32_t)ccr);
}

static void execute(bridge *b, const char *text, size_t n)
{
    cursor c;
    number ch, value;
    size_t ch_first = 0, ch_end = 0;
    int pulse;
    c.s = text;
    c.n = n;
    c.pos = 0;
    if ((pulse = take_word(&c, "PW ")) != 0 || take_word(&c, "SET ")) {
        if (take_digits(&c, &ch, &ch_first)) {
            ch_end = c.pos;
            if (take_word(&c, " ") && take_value(&c, &value) && at_end(&c)) {
                command_output(b, pulse, &c, &ch, ch_first, ch_end, &value);
                return;
            }
        }
    } else if (take_word(&c, "GET ")) {
        if (take_digits(&c, &ch, &ch_first) && at_end(&c)) {
            if (ch.mag < 1u || ch.mag > b->cfg.channels) {
                reply_no_channel(b, &c, ch_first, c.pos);
            } else {
                reply_value(b, b->ccr[ch.mag - 1u]);
            }
            return;
        }
    } else if (is_exactly(&c, "STOP")) {
        bridge_all_neutral(b);
        reply(b, "OK", "");
        return;
    } else if (is_exactly(&c, "HB")) {
        reply(b, "OK", "");
        return;
    } else if (is_exactly(&c, "PING")) {
        reply(b, "OK ", BRIDGE_VERSION);
        return;
    }
    reply(b, "ERR unknown command", "");
}

static void end_of_line(bridge *b, uint32_t now_ms)
{
    size_t start = 0, end = b->len, i;
    if (!b->overflow && b->len == 0u) {
        return;  /* an empty line (e.g. between \r and \n) is no line */
    }
    b->last_line_ms = now_ms;
    b->armed = 1u;
    if (b->overflow) {
        reply(b, "ERR line too long", "");
    } else {
        for (i = 0; i < b->len; i++) {
            if ((unsigned char)b->line[i] >= 0x80u) {
                break;
            }
        }
        if (i < b->len) {
            reply(b, "ERR bad line", "");
        } else {
            while (start < end && is_space(b->line[start])) {
                start++;
            }
            while (end > start && is_space(b->line[end - 1u])) {
                end--;
            }
            execute(b, b->line + start, end - start);
        }
    }
    b->len = 0u;
    b->overflow = 0u;
}

int bridge_init(bridge *b, const bridge_config *cfg, const bridge_hooks *hooks, uint32_t now_ms)
{
    if (cfg->timer_clock_hz == 0u || cfg->arr == 0u || cfg->ccr_max > cfg->arr ||
        cfg->neutral_ccr < cfg->ccr_min || cfg->neutral_ccr > cfg->ccr_max || cfg->channels < 1u ||
        cfg->channels > BRIDGE_MAX_CHANNELS || hooks->set_compare == NULL || hooks->write == NULL) {
        return -1;
    }
    b->cfg = *cfg;
    b->hooks = *hooks;
    b->len = 0u;
    b->overflow = 0u;
    b->armed = 0u;
    b->last_line_ms = now_ms;
    b->next_telemetry_ms = now_ms;
    b->watchdog_trips = 0u;
    bridge_all_neutral(b);
    return 0;
}

void bridge_feed(bridge *b, const uint8_t *data, size_t n, uint32_t now_ms)
{
    size_t i;
    for (i = 0; i < n; i++) {
        char c = (char)data[i];
        if (c == '\n' || c == '\r') {
            end_of_line(b, now_ms);
        } else if (b->len < BRIDGE_MAX_LINE) {
            b->line[b->len++] = c;
        } else {
            b->overflow = 1u;
        }
    }
}

/* "<int>.<frac>" of a fixed-point value with `digits` decimals, appended to `buf`. */
static size_t append_fixed(char *buf, size_t len, size_t cap, int32_t v, unsigned digits)
{
    char num[NUM_BUF];
    uint32_t scale = 1u, mag;
    unsigned i;
    for (i = 0; i < digits; i++) {
        scale *= 10u;
    }
    mag = v < 0 ? (uint32_t)(-(v + 1)) + 1u : (uint32_t)v;
    if (v < 0) {
        len = append(buf, len, cap, "-");
    }
    format_u64(num, mag / scale);
    len = append(buf, len, cap, num);
    len = append(buf, len, cap, ".");
    format_u64(num, (uint64_t)scale + mag % scale);
    return append(buf, len, cap, num + 1);  /* the leading 1 of scale keeps the zeros */
}

static void send_telemetry(bridge *b)
{
    bridge_telemetry t;
    char buf[64];
    size_t len;
    if (!b->hooks.read_telemetry(b->hooks.ctx, &t)) {
        return;
    }
    len = append(buf, 0, sizeof buf - 1u, "TEL ");
    len = append_fixed(buf, len, sizeof buf - 1u, t.speed_drpm, 1u);
    len = append(buf, len, sizeof buf - 1u, " ");
    len = append_fixed(buf, len, sizeof buf - 1u, t.current_ma, 3u);
    len = append(buf, len, sizeof buf - 1u, " ");
    len = append_fixed(buf, len, sizeof buf - 1u, t.voltage_cv, 2u);
    buf[len++] = '\n';
    send(b, buf, len);
}

void bridge_tick(bridge *b, uint32_t now_ms)
{
    if (b->cfg.watchdog_ms != 0u && b->armed && now_ms - b->last_line_ms > b->cfg.watchdog_ms) {
        bridge_all_neutral(b);
        b->watchdog_trips++;
        b->armed = 0u;
        b->len = 0u;  /* a line cut off by the trip is discarded, never run after it */
        b->overflow = 0u;
    }
    if (b->cfg.telemetry_ms != 0u && b->hooks.read_telemetry != NULL &&
        (int32_t)(now_ms - b->next_telemetry_ms) >= 0) {
        b->next_telemetry_ms = now_ms + b->cfg.telemetry_ms;
        send_telemetry(b);
    }
}
