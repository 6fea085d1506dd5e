/* Test stand-in for the Arduino Servo library: like the real one, a pulse is clamped to the
 * attach() limits (default MIN_PULSE_WIDTH..MAX_PULSE_WIDTH); the pulse each pin carries is
 * kept in servo_pulse_us for the test to print. */
#ifndef SERVO_STUB_H
#define SERVO_STUB_H
#define MIN_PULSE_WIDTH 544
#define MAX_PULSE_WIDTH 2400

extern int servo_pulse_us[64];

class Servo {
public:
    void attach(int pin, int min_us = MIN_PULSE_WIDTH, int max_us = MAX_PULSE_WIDTH)
    {
        pin_ = pin;
        min_ = min_us;
        max_ = max_us;
    }
    void writeMicroseconds(int us)
    {
        servo_pulse_us[pin_] = us < min_ ? min_ : (us > max_ ? max_ : us);
    }

private:
    int pin_ = 0, min_ = MIN_PULSE_WIDTH, max_ = MAX_PULSE_WIDTH;
};
#endif
