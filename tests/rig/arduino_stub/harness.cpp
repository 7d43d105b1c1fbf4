// Runs the psrig_lights sketch on the host. stdin holds one record per line:
//   S <hex bytes>   these bytes arrive on the serial line; loop() runs until they are read
//   T <ms>          the clock (millis) moves to <ms>; loop() runs once
//   L               prints "#LIT <index or -1>"
// After each record the harness prints "#END" on a line of its own, so replies can be told
// apart per record. The sketch itself is #included after Arduino.h by the test's build.
#include "Arduino.h"

unsigned long stub_millis = 0;
int stub_interlock = LOW;
int stub_pins[64];
StubSerial Serial;

#include "sketch.inc"

static int hexval(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

int main() {
  setup();
  static char record[20000];
  while (fgets(record, sizeof record, stdin)) {
    if (record[0] == 'S') {
      for (char *p = record + 2; hexval(p[0]) >= 0 && hexval(p[1]) >= 0; p += 2)
        Serial.push((unsigned char)(hexval(p[0]) * 16 + hexval(p[1])));
      while (Serial.available()) loop();
      loop();
    } else if (record[0] == 'T') {
      stub_millis = strtoul(record + 2, NULL, 10);
      loop();
    } else if (record[0] == 'L') {
      printf("#LIT %d\n", lit);
    }
    Serial.head = Serial.tail = 0;
    printf("#END\n");
    fflush(stdout);
  }
  return 0;
}
