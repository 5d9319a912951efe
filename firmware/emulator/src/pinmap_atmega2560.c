/* SPDX-License-Identifier: GPL-3.0-or-later */
/* pinmap_atmega2560.c - the Mega 2560 map of firmware/avr/pins.h as a table. */
#define DTHC_PINS_ATMEGA2560 1
#include "pins.h"
#include "pinmap.h"

const struct board_pins pinmap_atmega2560 = {
	.mcu = "atmega2560",
	.in = {
		PINMAP_PIN(PIN_ARC_OK), PINMAP_PIN(PIN_OHMIC), PINMAP_PIN(PIN_FLOAT),
		PINMAP_PIN(PIN_BREAKAWAY), PINMAP_PIN(PIN_THC_UP), PINMAP_PIN(PIN_THC_DOWN),
		PINMAP_PIN(PIN_ESTOP), PINMAP_PIN(PIN_Z_LIMIT_MIN), PINMAP_PIN(PIN_Z_LIMIT_MAX),
	},
	.arc_vtof = PINMAP_PIN(PIN_ARC_VTOF),
	PINMAP_COMMON,
};
