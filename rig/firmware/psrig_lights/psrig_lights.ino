/*
  psrig_lights - light-controller firmware speaking "psrig light protocol 1".

  Board: Arduino Mega 2560 (54 digital pins, enough for 32 lights); any board works with a
  shorter LIGHT_PINS list. Each pin drives a logic-level MOSFET or LED driver's enable input
  (HIGH = lit). Pins with PWM dim with LEVEL; others are simply on when their level is > 0.

  Serial: 115200 baud, 8N1, ASCII lines ending in "\n" ("\r" is ignored).

    ID?               -> PSRIG-LIGHTS 1 <count>
    ON <i>            -> OK ON <i>          exactly light i lit, all others off
    OFF               -> OK OFF
    LEVEL <i> <0-255> -> OK LEVEL <i> <v>
    STATE?            -> STATE <i or ->
    anything wrong    -> ERR <code> <text>  1 unknown command, 2 bad index, 3 interlock

  Light indices are 0-BASED on the wire, as in psrig's Python code: "ON 0" lights LIGHT_PINS[0].

  Safety:
  - Command watchdog: when no command line arrives for 5 s, every light is switched off
    (a crashed or unplugged host never leaves a light burning). Any line counts, so a host that
    waits longer between commands sends "STATE?" as a keep-alive.
  - Interlock: INTERLOCK_PIN (INPUT_PULLUP) must read LOW (enclosure closed, switch to GND);
    when it opens, everything goes off and ON is refused with "ERR 3 interlock open".
    Set INTERLOCK_PIN to -1 on rigs without an interlock switch.
  - The AVR hardware watchdog resets a hung board within 2 s; setup() starts with all lights off.
  - Opening the USB serial port resets the board (DTR); the host waits about 2 s for the
    bootloader before it sends "ID?". Bytes sent during that time are lost, by design.

  This sketch is mirrored by rig/sim/firmware.py, which the tests run against the host driver
  rig/lights.py; change the two together.
*/

#include <avr/wdt.h>

const uint8_t LIGHT_PINS[] = {
  22, 23, 24, 25, 26, 27, 28, 29, 30, 31, 32, 33, 34, 35, 36, 37,
  38, 39, 40, 41, 42, 43, 44, 45, 46, 47, 48, 49, 50, 51, 52, 53,
};
const int LIGHT_COUNT = sizeof(LIGHT_PINS) / sizeof(LIGHT_PINS[0]);
const int INTERLOCK_PIN = 12;            // -1: no interlock switch fitted
const unsigned long WATCHDOG_MS = 5000;  // command watchdog of the protocol
const uint8_t MAX_LINE = 64;             // longer lines get "ERR 1 line too long"

uint8_t levels[LIGHT_COUNT];
int lit = -1;                 // index of the light on, -1 when all are off
unsigned long lastCommand = 0;
char line[MAX_LINE + 1];
uint8_t lineLength = 0;
bool overflow = false;        // skipping the rest of an over-long line

// Replies end in "\n" alone (Serial.println would send "\r\n"; the host would cope, but the
// simulated firmware, which the tests check, sends "\n").
template <typename T> void say(T value) {
  Serial.print(value);
  Serial.print('\n');
}

void applyLight(int index, bool on) {
  uint8_t pin = LIGHT_PINS[index];
  if (!on || levels[index] == 0) {
    digitalWrite(pin, LOW);
  } else if (digitalPinHasPWM(pin) && levels[index] < 255) {
    analogWrite(pin, levels[index]);
  } else {
    digitalWrite(pin, HIGH);
  }
}

void allOff() {
  for (int i = 0; i < LIGHT_COUNT; i++) applyLight(i, false);
  lit = -1;
}

bool interlockOpen() {
  return INTERLOCK_PIN >= 0 && digitalRead(INTERLOCK_PIN) == HIGH;
}

// Parse a decimal index in 0 .. LIGHT_COUNT-1; -1 when the word is anything else.
int parseIndex(const char *word) {
  if (word == NULL || *word == '\0' || strlen(word) > 4) return -1;
  for (const char *c = word; *c; c++) if (*c < '0' || *c > '9') return -1;
  int value = atoi(word);
  return value < LIGHT_COUNT ? value : -1;
}

void replyBadIndex(const char *word) {
  Serial.print(F("ERR 2 bad index "));
  say(word ? word : "");
}

void execute(char *text) {
  char *name = strtok(text, " \t");
  char *arg1 = strtok(NULL, " \t");
  char *arg2 = strtok(NULL, " \t");
  char *extra = strtok(NULL, " \t");
  if (name == NULL) return;

  if (!strcmp(name, "ID?") && !arg1) {
    Serial.print(F("PSRIG-LIGHTS 1 "));
    say(LIGHT_COUNT);
  } else if (!strcmp(name, "STATE?") && !arg1) {
    Serial.print(F("STATE "));
    if (lit < 0) say('-'); else say(lit);
  } else if (!strcmp(name, "OFF") && !arg1) {
    allOff();
    say(F("OK OFF"));
  } else if (!strcmp(name, "ON") && arg1 && !arg2) {
    int index = parseIndex(arg1);
    if (index < 0) { replyBadIndex(arg1); return; }
    if (interlockOpen()) { allOff(); say(F("ERR 3 interlock open")); return; }
    // Off first, then on: two lights are never lit at once, not even for a microsecond.
    allOff();
    applyLight(index, true);
    lit = index;
    Serial.print(F("OK ON "));
    say(index);
  } else if (!strcmp(name, "LEVEL") && arg1 && arg2 && !extra) {
    int index = parseIndex(arg1);
    if (index < 0) { replyBadIndex(arg1); return; }
    bool digits = strlen(arg2) <= 3;
    for (const char *c = arg2; *c; c++) if (*c < '0' || *c > '9') digits = false;
    int value = atoi(arg2);
    if (!digits || value > 255) {
      Serial.print(F("ERR 1 bad level "));
      say(arg2);
      return;
    }
    levels[index] = value;
    if (lit == index) applyLight(index, true);
    Serial.print(F("OK LEVEL "));
    Serial.print(index);
    Serial.print(' ');
    say(value);
  } else {
    say(F("ERR 1 unknown command"));
  }
}

void readSerial() {
  while (Serial.available() > 0) {
    char c = Serial.read();
    if (c == '\r') continue;
    if (c == '\n') {
      line[lineLength] = '\0';
      bool skip = overflow;
      overflow = false;
      lineLength = 0;
      if (skip || line[0] == '\0') continue;
      lastCommand = millis();
      execute(line);
    } else if (overflow) {
      // drop the rest of an over-long line
    } else if (lineLength < MAX_LINE) {
      line[lineLength++] = c;
    } else {
      say(F("ERR 1 line too long"));
      overflow = true;
      lineLength = 0;
    }
  }
}

void setup() {
  wdt_disable();
  for (int i = 0; i < LIGHT_COUNT; i++) {
    pinMode(LIGHT_PINS[i], OUTPUT);
    levels[i] = 255;
  }
  allOff();
  if (INTERLOCK_PIN >= 0) pinMode(INTERLOCK_PIN, INPUT_PULLUP);
  Serial.begin(115200);
  lastCommand = millis();
  wdt_enable(WDTO_2S);
}

void loop() {
  wdt_reset();
  readSerial();
  if (lit >= 0 && (millis() - lastCommand > WATCHDOG_MS || interlockOpen())) {
    allOff();
  }
}
