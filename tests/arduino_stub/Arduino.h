/* Test stand-in for the Arduino core the sketch uses: Serial reads stdin and writes stdout,
 * millis() is a counter the test's main advances. */
#ifndef ARDUINO_STUB_H
#define ARDUINO_STUB_H
#include <stddef.h>
#include <stdint.h>

unsigned long millis();
void analogWrite(uint8_t pin, int duty);

struct SerialPort {
    void begin(long baud);
    int available();
    int read();
    size_t write(const uint8_t *bytes, size_t n);
};
extern SerialPort Serial;
#endif
