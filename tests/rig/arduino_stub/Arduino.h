// A host stub of the few Arduino calls rig/firmware/psrig_lights/psrig_lights.ino makes, so the
// sketch compiles with g++ or clang++ on this machine (tests/rig/test_firmware_parity.py).
// Serial reads from an input queue the harness fills and writes to stdout; millis() is a
// clock the harness sets; pins only remember what was written to them.
#ifndef PSRIG_ARDUINO_STUB_H
#define PSRIG_ARDUINO_STUB_H

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define HIGH 1
#define LOW 0
#define INPUT 0
#define OUTPUT 1
#define INPUT_PULLUP 2
#define F(x) (x)
#define digitalPinHasPWM(p) ((p) >= 2 && (p) <= 13)
#define WDTO_2S 7

extern unsigned long stub_millis;   // the harness's clock, milliseconds
extern int stub_interlock;          // level read on the interlock pin (LOW: closed)
extern int stub_pins[64];           // last value written to each pin (0-255)

static inline unsigned long millis() { return stub_millis; }
static inline void pinMode(uint8_t, uint8_t) {}
static inline void digitalWrite(uint8_t pin, uint8_t v) { stub_pins[pin] = v ? 255 : 0; }
static inline void analogWrite(uint8_t pin, int v) { stub_pins[pin] = v; }
static inline int digitalRead(uint8_t) { return stub_interlock; }
static inline void wdt_enable(int) {}
static inline void wdt_disable() {}
static inline void wdt_reset() {}

struct StubSerial {
  unsigned char in[8192];
  int head = 0, tail = 0;
  void begin(long) {}
  void push(unsigned char c) { if (tail < (int)sizeof(in)) in[tail++] = c; }
  int available() { return tail - head; }
  int read() { return head < tail ? in[head++] : -1; }
  void print(const char *s) { fputs(s, stdout); }
  void print(char c) { putchar(c); }
  void print(int v) { printf("%d", v); }
  void print(unsigned v) { printf("%u", v); }
};
extern StubSerial Serial;

#endif
