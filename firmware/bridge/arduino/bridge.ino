// rigtool bridge firmware 1.0 on an Arduino: the same C core, for labs that drive ESCs from
// an Arduino. `make arduino` copies this sketch with bridge_core.c/.h and bridge_rig.h into
// build/bridge/ (Arduino compiles only files in the sketch folder) and runs arduino-cli.
//
// Two outputs (choose with BRIDGE_ARDUINO_ANALOG):
//  - Servo (default): ESC pulses with Servo::writeMicroseconds on pins 9, 10, 11, 12. The
//    "timer" is 1 us per count at 50 Hz, so counts are microseconds. Rig file:
//      command_unit: pulse_us, timer_clock_hz: 1000000, psc: 0, arr: 19999, neutral: 1500
//    (f_PWM = 1 MHz / (1 * 20000) = 50 Hz). The Servo library puts out 544..2400 us only
//    (MIN_PULSE_WIDTH..MAX_PULSE_WIDTH), so the core's output range is that: SET/PW outside it
//    get `ERR out of range 544..2400`, never an `OK` for a pulse the pin does not carry.
//  - analogWrite: duty CCR/255 on pins 5, 6 (976.6 Hz = 16 MHz / (64 * 256), the formula's
//    f_TIM 16 MHz, PSC 63, ARR 255) and 9, 10 (490 Hz phase-correct). Rig file:
//      command_unit: pwm_counts, timer_clock_hz: 16000000, psc: 63, arr: 255, neutral: 0
// An Uno resets when the port opens (DTR) and boots for about 1.5 s: the driver's PING at open
// then times out unless auto-reset is disabled (10 uF from RESET to GND) or the port is opened
// once beforehand.
#ifdef BRIDGE_ARDUINO_ANALOG
#define BRIDGE_TIMER_CLOCK_HZ 16000000ul
#define BRIDGE_PSC 63ul
#define BRIDGE_ARR 255ul
#define BRIDGE_NEUTRAL_CCR 0ul
static const uint8_t PINS[4] = {5, 6, 9, 10};
#else
#include <Servo.h>
#define BRIDGE_TIMER_CLOCK_HZ 1000000ul
#define BRIDGE_PSC 0ul
#define BRIDGE_ARR 19999ul
#define BRIDGE_NEUTRAL_CCR 1500ul
#define BRIDGE_CCR_MIN ((uint32_t)MIN_PULSE_WIDTH)  /* 544 us */
#define BRIDGE_CCR_MAX ((uint32_t)MAX_PULSE_WIDTH)  /* 2400 us */
static const uint8_t PINS[4] = {9, 10, 11, 12};
static Servo servos[4];
#endif

#include "bridge_core.h"
#include "bridge_rig.h"

static bridge core;

static void set_compare(void *ctx, uint8_t ch, uint32_t ccr)
{
  (void)ctx;
#ifdef BRIDGE_ARDUINO_ANALOG
  analogWrite(PINS[ch - 1], (int)ccr);
#else
  servos[ch - 1].writeMicroseconds((int)ccr);
#endif
}

static void write_bytes(void *ctx, const char *bytes, size_t n)
{
  (void)ctx;
  Serial.write((const uint8_t *)bytes, n);
}

void setup()
{
  static const bridge_config cfg = {BRIDGE_TIMER_CLOCK_HZ, BRIDGE_PSC, BRIDGE_ARR,
                                    BRIDGE_NEUTRAL_CCR, BRIDGE_WATCHDOG_MS, 0, BRIDGE_CHANNELS,
                                    BRIDGE_CCR_MIN, BRIDGE_CCR_MAX};
  static const bridge_hooks hooks = {set_compare, write_bytes, NULL, NULL};
#ifndef BRIDGE_ARDUINO_ANALOG
  for (uint8_t i = 0; i < BRIDGE_CHANNELS; i++) {
    servos[i].attach(PINS[i], (int)BRIDGE_CCR_MIN, (int)BRIDGE_CCR_MAX);
  }
#endif
  bridge_init(&core, &cfg, &hooks, millis());  // every channel at neutral before the port opens
  Serial.begin(115200);
}

void loop()
{
  while (Serial.available() > 0) {
    uint8_t byte = (uint8_t)Serial.read();
    bridge_feed(&core, &byte, 1, millis());
  }
  bridge_tick(&core, millis());  // the watchdog: neutral when the host falls silent
}
