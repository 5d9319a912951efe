/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * pinmap.h - firmware/avr/pins.h as a run-time table, one per MCU (pins.h selects its map
 * with a macro, so each map is compiled in its own file: pinmap_atmega2560.c and
 * pinmap_atmega328p.c).
 */
#ifndef DTHC_EMU_PINMAP_H
#define DTHC_EMU_PINMAP_H

#define PINMAP_INPUTS 9 /* ARC_OK .. Z_LIMIT_MAX, protocol bit order */

struct pin_map {
	char port; /* 'A'.., 0 when the build has no such pin */
	int bit;
};

struct board_pins {
	const char *mcu;
	struct pin_map in[PINMAP_INPUTS];
	struct pin_map step, dir, torch, ohmic_en, z_en;
	struct pin_map arc_vtof; /* T5 on the Mega (the V-to-F card); {0, 0}: no such input */
	int arc_adc;
	long arc_divider;
	long adc_ref_mv;
	long steps_per_mm;
	long z_boot_um;
	long z_min_um;
	long z_max_um;
	unsigned long uart_baud;
};

extern const struct board_pins pinmap_atmega2560;
extern const struct board_pins pinmap_atmega328p;

#define PINMAP_STR_(x) #x
#define PINMAP_LETTER(x) (PINMAP_STR_(x)[0])
#define PINMAP_PIN(name) { PINMAP_LETTER(name##_PORT), name##_BIT }

#define PINMAP_COMMON                                                                  \
	.step = PINMAP_PIN(PIN_STEP), .dir = PINMAP_PIN(PIN_DIR),                       \
	.torch = PINMAP_PIN(PIN_TORCH), .ohmic_en = PINMAP_PIN(PIN_OHMIC_ENABLE),       \
	.z_en = PINMAP_PIN(PIN_Z_ENABLE), .arc_adc = PIN_ARC_ADC,                       \
	.arc_divider = DTHC_ARC_DIVIDER, .adc_ref_mv = DTHC_ADC_REF_MV,                 \
	.steps_per_mm = DTHC_Z_STEPS_PER_MM, .z_boot_um = DTHC_Z_BOOT_UM,               \
	.z_min_um = DTHC_Z_MIN_UM, .z_max_um = DTHC_Z_MAX_UM, .uart_baud = DTHC_UART_BAUD

#endif
