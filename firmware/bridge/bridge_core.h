/* rigtool bridge firmware 1.0: the portable protocol core (docs/drivers/stm32-bridge.md).
 *
 * C99, no libc I/O and no heap: the glue hands in received bytes and a millisecond tick,
 * and the core answers through two hooks, set_compare(ch, ccr) and write(bytes). */
#ifndef BRIDGE_CORE_H
#define BRIDGE_CORE_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define BRIDGE_VERSION "rigtool-bridge 1.0"
#define BRIDGE_MAX_LINE 64u     /* bytes between line ends; a longer line is refused whole */
#define BRIDGE_MAX_CHANNELS 4u  /* timer channels 1..4 */

/* Telemetry in fixed point, so the core needs no floating point. */
typedef struct {
    int32_t speed_drpm;   /* 0.1 rpm */
    int32_t current_ma;   /* mA */
    int32_t voltage_cv;   /* 10 mV */
} bridge_telemetry;

typedef struct {
    /* Put compare value `ccr` (0..arr) on timer channel `ch` (1..channels). */
    void (*set_compare)(void *ctx, uint8_t ch, uint32_t ccr);
    /* Send `n` bytes to the host (a whole reply line, `\n` included). */
    void (*write)(void *ctx, const char *bytes, size_t n);
    /* Optional (NULL = no telemetry): fill `out`, return nonzero if it holds a sample. */
    int (*read_telemetry)(void *ctx, bridge_telemetry *out);
    void *ctx;
} bridge_hooks;

typedef struct {
    uint32_t timer_clock_hz;  /* f_TIM */
    uint32_t psc;             /* prescaler: tick = (psc + 1) / f_TIM */
    uint32_t arr;             /* auto-reload: compare values 0..arr */
    uint32_t neutral_ccr;     /* STOP and the watchdog put every channel here */
    uint32_t watchdog_ms;     /* 0 = no watchdog */
    uint32_t telemetry_ms;    /* 0 = no telemetry lines */
    uint8_t channels;         /* 1..BRIDGE_MAX_CHANNELS */
    uint32_t ccr_min;         /* the compare values the output can put out: ccr_min..ccr_max */
    uint32_t ccr_max;         /* (a timer: 0..arr; Arduino Servo: 544..2400 us) */
} bridge_config;

typedef struct {
    bridge_config cfg;
    bridge_hooks hooks;
    uint32_t ccr[BRIDGE_MAX_CHANNELS];
    char line[BRIDGE_MAX_LINE];
    size_t len;
    uint8_t overflow;        /* the current line passed BRIDGE_MAX_LINE: refuse it at its end */
    uint8_t armed;           /* a line arrived since boot or the last watchdog trip */
    uint32_t last_line_ms;
    uint32_t next_telemetry_ms;
    uint32_t watchdog_trips;
} bridge;

/* Check `cfg`, keep the hooks and put every channel at neutral. 0 on success, -1 if the
 * config is inconsistent (no clock, arr 0, not ccr_min <= neutral <= ccr_max <= arr, channels
 * outside 1..4, no hooks). */
int bridge_init(bridge *b, const bridge_config *cfg, const bridge_hooks *hooks, uint32_t now_ms);

/* Take `n` received bytes; every complete line is answered before this returns. */
void bridge_feed(bridge *b, const uint8_t *data, size_t n, uint32_t now_ms);

/* Run the watchdog and telemetry; call it often (every millisecond or main-loop pass). A
 * watchdog trip also discards a partial line: bytes sent before the trip never run after it. */
void bridge_tick(bridge *b, uint32_t now_ms);

/* Every channel to neutral (STOP, the watchdog, and glue shutdown paths). */
void bridge_all_neutral(bridge *b);

#ifdef __cplusplus
}
#endif

#endif
