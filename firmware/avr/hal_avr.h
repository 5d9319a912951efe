/* hal_avr.h - what main.c needs of hal_avr.c beyond firmware/hal/hal.h. */
#ifndef DTHC_HAL_AVR_H
#define DTHC_HAL_AVR_H

#include <stdbool.h>
#include <stdint.h>

void hal_init(void);  /* pins (outputs off), UART, ADC, step timer; interrupts still off */
void hal_start(void); /* the clock and the sample tick, continuous ADC */
/* The main loop's watchdog kick; the tick counts the time since it (HAL_HEALTH_LOOP_STALL). */
void hal_watchdog_kick(void);
bool hal_uart_rx_pending(void);
extern volatile uint16_t hal_rx_discarded; /* bytes the receive interrupt discarded */

#endif /* DTHC_HAL_AVR_H */
