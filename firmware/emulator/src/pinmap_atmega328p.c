/* SPDX-License-Identifier: GPL-3.0-or-later */
/* pinmap_atmega328p.c - the Nano/Uno map of firmware/avr/pins.h as a table (no THC up/down
 * and no Z limit inputs in this build). */
#define DTHC_PINS_ATMEGA328P 1
#include "pins.h"
#include "pinmap.h"

const struct board_pins pinmap_atmega328p = {
	.mcu = "atmega328p",
	.in = {
		PINMAP_PIN(PIN_ARC_OK), PINMAP_PIN(PIN_OHMIC), PINMAP_PIN(PIN_FLOAT),
		PINMAP_PIN(PIN_BREAKAWAY), {0, 0}, {0, 0},
		PINMAP_PIN(PIN_ESTOP), {0, 0}, {0, 0},
	},
	.arc_vtof = {0, 0}, /* T1 (PD5) is OHMIC: no V-to-F option on the Nano */
	PINMAP_COMMON,
};
