/* Runs the Arduino sketch's setup() and loop() on the stand-ins: host lines on stdin, the
 * sketch's replies on stdout, then "pin <n> <us>" for the pulse each servo pin carries. */
#include <stdio.h>
#include <unistd.h>

#include "Arduino.h"

void setup();
void loop();

int servo_pulse_us[64];
SerialPort Serial;
static unsigned long now_ms;
static uint8_t input[4096];
static size_t input_len, input_pos;

unsigned long millis() { return now_ms; }
void analogWrite(uint8_t, int) {}
void SerialPort::begin(long) {}
int SerialPort::available() { return (int)(input_len - input_pos); }
int SerialPort::read() { return input_pos < input_len ? input[input_pos++] : -1; }
size_t SerialPort::write(const uint8_t *bytes, size_t n) { return fwrite(bytes, 1, n, stdout); }

int main()
{
    ssize_t n;
    while ((n = ::read(0, input + input_len, sizeof input - input_len)) > 0) {
        input_len += (size_t)n;
    }
    setup();
    while (input_pos < input_len) {
        loop();
        now_ms++;
    }
    for (int pin = 9; pin <= 12; pin++) {
        printf("pin %d %d\n", pin, servo_pulse_us[pin]);
    }
    return 0;
}
