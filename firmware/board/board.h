/*
 * board.h - the portable board logic of the reference DTHC firmware (PROTOCOL.md).
 *
 * No hardware header anywhere below this directory: it runs on firmware/hal/hal.h only,
 * so the AVR build, the native unit tests and a later RP2040 port share it unchanged.
 */
#ifndef DTHC_BOARD_H
#define DTHC_BOARD_H

#include <stdbool.h>
#include <stdint.h>

/* Build-time sizes (a small MCU passes smaller ones with -D). */
#ifndef BOARD_MAX_BATCH
#define BOARD_MAX_BATCH 100 /* CONFIGURE.batch_size limit: sets the SAMPLES buffer */
#endif
#ifndef BOARD_MAX_RATE_HZ
#define BOARD_MAX_RATE_HZ 20000 /* CONFIGURE.sample_rate_hz limit: what the tick sustains */
#endif
#ifndef BOARD_MA_MAX
#define BOARD_MA_MAX 32 /* moving-average window limit */
#endif
#ifndef BOARD_LEASE_IDLE_LAPSE
/* 1: a lease that runs out at rest is reported, not latched (protocol 1.1, section 4). 0:
 * protocol 1.0's lease, latched at rest too: only the mock device builds it, as a board
 * that announces 1.1 without keeping its rule (mock_device/variants.py, idle-lapse-latched)
 * for the conformance suite to catch. */
#define BOARD_LEASE_IDLE_LAPSE 1
#endif
#ifndef BOARD_HOMING
/* 1: Z_HOME (protocol 1.3) is built in; it runs only on a board whose capabilities say
 * HOMING (a home switch on Z_LIMIT_MAX). 0: left out (the Nano: no switch pins, no RAM). */
#define BOARD_HOMING 1
#endif
#ifndef BOARD_CURRENT_OUT
#define BOARD_CURRENT_OUT 0 /* 1: SET_CURRENT drives hal_set_current_da (CURRENT_OUT) */
#endif

#define BOARD_FW_MAJOR 0
#define BOARD_FW_MINOR 1
#define BOARD_FW_PATCH 0

/* What the hardware is; filled by the port's main() (from pins.h on AVR). */
typedef struct {
    const char *serial;      /* printable ASCII, at most 16 characters */
    uint32_t capabilities;   /* HELLO_INFO capability bits this build really has */
    int32_t z_min_um;        /* soft limits */
    int32_t z_max_um;
    int32_t z_boot_um;       /* Z at power-on (no homing) */
    int32_t z_max_speed_um_s;
    int32_t z_accel_um_s2;
    uint16_t z_steps_per_mm;
    uint8_t reset_reason;    /* PROTOCOL.md section 6.2 table */
#if BOARD_HOMING
    int32_t z_home_um;       /* Z where the home switch (Z_LIMIT_MAX) trips: above z_max_um */
#endif
} board_config_t;

/* Start: no session, torch off, Z idle, 1 kHz x 5, filter none, cal 0.01 V per count. The
 * entropy seeds the boot id (made final with the arrival time of the first host frame). */
void board_init(const board_config_t *cfg, uint32_t entropy);

/* One sample period, from the tick interrupt: inputs and EVENTs, lease, faults, probe stop,
 * Z profile, one sample and its batch. t_us is the tick's scheduled time. */
void board_tick(uint32_t t_us);

/* Main loop: feed received bytes to the codec and answer frames. Returns true when it
 * did something (the caller may sleep otherwise). */
bool board_poll(void);

#endif /* DTHC_BOARD_H */
