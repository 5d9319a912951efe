/*
 * arc_vtof.h - the arc voltage from a voltage-to-frequency card (THCAD type) on Timer5's
 * external clock pin T5 (PL2, Arduino D47): the Mega 2560's build option DTHC_ARC_VTOF
 * (make -C firmware vtof). hal_avr.c calls these; hal_arc_raw() (firmware/hal/hal.h) is
 * defined in arc_vtof.c instead of the ADC front end in hal_avr.c.
 */
#ifndef DTHC_ARC_VTOF_H
#define DTHC_ARC_VTOF_H

#include <stdint.h>

void arc_vtof_init(void);                         /* the pin and Timer5, counting */
void arc_vtof_start(void);                        /* after the clock runs: first reading */
void arc_vtof_set_period_us(uint16_t period_us);  /* the sample period (tick locked) */

#endif /* DTHC_ARC_VTOF_H */
