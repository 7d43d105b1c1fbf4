// Stub of <avr/wdt.h>: the watchdog calls live in Arduino.h (a host has no AVR watchdog).
#include "Arduino.h"
