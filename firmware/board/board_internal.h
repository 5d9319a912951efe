/* board_internal.h - state shared by the board logic's files (not for the HAL). */
#ifndef DTHC_BOARD_INTERNAL_H
#define DTHC_BOARD_INTERNAL_H

#include <stdbool.h>
#include <stdint.h>

#include "../../firmware_protocol/c/dthc_protocol.h"
#include "../hal/hal.h"
#include "board.h"

#define BOARD_FAULT_CODES 6     /* LEASE_EXPIRED .. INTERNAL */
#define BOARD_OUTCOMES DTHC_HOST_WINDOW
#define BOARD_NO_OUTCOME 0xFF
#define BOARD_CONTACT_SENSORS ((1u << DTHC_INPUT_OHMIC) | (1u << DTHC_INPUT_FLOAT))
#define BOARD_FAULT_REPEAT_US ((uint32_t)DTHC_FAULT_REPEAT_MS * 1000u)

/* Reports built under the tick lock (or in the tick) go through this small buffer. */
#define BOARD_SMALL_PAYLOAD DTHC_EVENT_SIZE /* EVENT and FAULT, the largest report */
typedef char board_small_reports_fit[(DTHC_FAULT_SIZE <= BOARD_SMALL_PAYLOAD
                                      && DTHC_PROBE_RESULT_SIZE <= BOARD_SMALL_PAYLOAD
                                      && DTHC_MOTION_DONE_SIZE <= BOARD_SMALL_PAYLOAD
                                      && DTHC_HOME_RESULT_SIZE <= BOARD_SMALL_PAYLOAD
                                      && DTHC_NAK_SIZE <= BOARD_SMALL_PAYLOAD) ? 1 : -1];
#define BOARD_SMALL_TX (DTHC_TX_PAYLOAD_OFFSET + BOARD_SMALL_PAYLOAD + 6)
/* SAMPLES, encoded in place where the samples were collected (dthc_encode_in_place). */
#define BOARD_SAMPLES_PAYLOAD (DTHC_SAMPLES_HEADER_SIZE + 2 * BOARD_MAX_BATCH)
#define BOARD_SAMPLES_TX (BOARD_SAMPLES_PAYLOAD + 4 + 2 + 1 + 1)
/* Query replies (HELLO_INFO is the largest), encoded in place outside the lock. */
#define BOARD_QUERY_PAYLOAD DTHC_HELLO_INFO_SIZE
typedef char board_query_replies_fit[(DTHC_STATUS_SIZE <= BOARD_QUERY_PAYLOAD
                                      && DTHC_CLOCK_SIZE <= BOARD_QUERY_PAYLOAD) ? 1 : -1];
#define BOARD_QUERY_TX (DTHC_TX_PAYLOAD_OFFSET + BOARD_QUERY_PAYLOAD + 6)

typedef enum { Z_IDLE, Z_MOVE, Z_PROBE, Z_VELOCITY, Z_STOPPING, Z_HOME } z_mode_t;

/* The steps of a Z_HOME cycle (PROTOCOL.md section 6.1), in the order they run. */
typedef enum {
    HOME_OFF_FIRST,   /* the switch was closed at the start: down until it opens */
    HOME_CLEAR_FIRST, /* then down backoff_um more */
    HOME_SEEK,        /* up fast until it closes */
    HOME_OFF,         /* down until it opens */
    HOME_CLEAR,       /* then down backoff_um more */
    HOME_LOCATE,      /* up slowly until it closes: the home position */
    HOME_RETRACT      /* down to the home position less backoff_um */
} home_phase_t;

/* The host lease (PROTOCOL.md section 4): running; ran out at rest (reported, nothing
 * latched: the next valid frame renews it); ran out in use (LEASE_EXPIRED latched: only
 * FAULT_RESET re-arms it). */
typedef enum { LEASE_RUNNING, LEASE_LAPSED_IDLE, LEASE_EXPIRED } lease_state_t;

typedef struct {
    uint8_t seq;
    uint8_t code; /* 0: ACK, else the NAK code */
    uint8_t detail;
} outcome_t;

typedef struct {
    uint8_t valid;
    uint8_t seq;
    uint8_t result;
    int32_t z_um;
    uint32_t t_us;
} motion_report_t;

typedef struct {
    uint8_t valid;
    uint8_t seq;
    uint8_t result;
    uint16_t sensor;
    int32_t contact_z_um;
    int32_t stop_z_um;
    uint32_t t_us;
} probe_report_t;

typedef struct {
    uint8_t valid;
    uint8_t seq;
    uint8_t result;
    int32_t z_um;
    int32_t shift_um;
    uint32_t t_us;
} home_report_t;

typedef struct {
    const board_config_t *cfg;
    uint32_t boot_id;
    bool boot_id_final;
    uint32_t now_us; /* the current tick's time (tick context) */

    /* session and lease */
    bool session;
    uint8_t lease; /* lease_state_t (one byte: the Nano's RAM is short) */
    uint16_t lease_ms;
    uint32_t last_rx_us;

    /* duplicate memory: outcomes of the last 8 executed sequenced commands */
    outcome_t outcomes[BOARD_OUTCOMES];
    uint8_t outcome_next;
    uint16_t rx_duplicates;

    /* faults and events */
    uint16_t faults;
    uint32_t fault_counter[BOARD_FAULT_CODES];
    uint8_t fault_detail[BOARD_FAULT_CODES];
    uint32_t last_fault_report_us;
    uint32_t event_counter;

    /* outputs and inputs */
    bool torch;
    bool ohmic;
#if BOARD_CURRENT_OUT
    uint16_t current_da; /* the last SET_CURRENT */
#endif
    uint16_t inputs;
    bool arc_ok_seen;
    bool arc_off_timing;
    uint32_t arc_off_since_us;

    /* sampling */
    uint16_t rate_hz;
    uint16_t period_us;
    uint8_t batch_size;
    uint8_t filter_kind;
    uint16_t filter_param;
    uint16_t arc_lost_ms;
    int32_t cal_offset;
    uint32_t scale_m; /* cv = (raw - cal_offset) * scale_m >> scale_sh, scale_m < 2^14 */
    uint8_t scale_sh;
    uint16_t lp_alpha_q16;
    int32_t hist[BOARD_MA_MAX];
    uint8_t hist_len;
    uint8_t hist_pos;
    int32_t hist_sum;
    int32_t lp_q8;
    uint8_t n_batch;
    uint32_t batch_t0_us;
    uint16_t sample_seq;
    bool sample_overflow;

    /* Z */
    uint8_t z_mode;
    int32_t z_v_um_s;       /* commanded velocity now, positive up */
    int32_t z_dv_um_s;      /* velocity change allowed per tick */
    int32_t z_target_um;    /* Z_MOVE target */
    int32_t z_feed_um_s;    /* Z_MOVE / Z_PROBE feed, Z_VELOCITY velocity */
    uint8_t move_seq;       /* running Z_MOVE's seq, 0 for none */
    uint8_t probe_seq;      /* running Z_PROBE's (Z_PROBE_AWAY's) seq, 0 for none */
    bool probe_away;        /* Z_PROBE_AWAY: up until every sensor is released */
    uint16_t probe_sensors;
    int32_t probe_end_um;
    bool probe_to_limit;    /* the probe's end is the soft limit, not max travel */
    uint8_t probe_outcome;  /* BOARD_NO_OUTCOME while running */
    uint16_t probe_fired;   /* the sensors that fired; away: the ones last seen active */
    int32_t probe_contact_um; /* where contact (away: the release) was detected */
    uint16_t zvel_seq;
    bool zvel_applied;
    uint32_t zvel_expiry_us;
    motion_report_t last_motion;
    probe_report_t last_probe;
#if BOARD_HOMING
    int32_t z_base_um;      /* Z at step count 0: the boot position, until homed */
    bool homed;             /* status HOMED: z_base_um came from the home switch */
    uint8_t home_seq;       /* running Z_HOME's seq, 0 for none */
    uint8_t home_phase;     /* home_phase_t */
    uint8_t home_outcome;   /* BOARD_NO_OUTCOME while running */
    int32_t home_seek_um_s;
    int32_t home_locate_um_s;
    int32_t home_backoff_um;
    int32_t home_lo_steps;  /* max_travel_um either side of where homing started */
    int32_t home_hi_steps;
    int32_t home_shift_um;
    uint32_t home_deadline_us;
    home_report_t last_home;
#endif
} board_t;

extern board_t B;
extern dthc_rx_t board_rx;

/* board.c */
void board_latch(uint8_t code, uint8_t detail);
uint8_t board_status_bits(void);
uint8_t board_lowest_fault(void);
void board_set_torch(bool on);
void board_set_ohmic(bool on);
bool board_configure(const uint8_t *p, uint8_t *bad_field);
void board_send_small(uint8_t type, uint8_t seq, uint8_t len);
bool board_flush_samples(void);
/* A completed SAMPLES batch is waiting for the main loop. */
bool board_samples_waiting(void);
uint16_t board_tx_reserve(void);
bool board_queue(const uint8_t *wire, size_t n);
extern uint8_t board_small_tx[BOARD_SMALL_TX];
#define BOARD_SMALL_PAYLOAD_AT (board_small_tx + DTHC_TX_PAYLOAD_OFFSET)

/* board_motion.c */
int32_t board_z_um(void);
void board_z_init(void);
void board_z_update_dv(void);
void board_z_tick(void);
bool board_z_busy(void);
void board_z_end(uint8_t move_result, uint8_t probe_result);
void board_z_stop(void);
void board_z_move(uint8_t seq, int32_t target_um, uint32_t feed_um_s);
void board_z_probe(uint8_t seq, uint32_t feed_um_s, uint32_t max_travel_um, uint16_t sensors,
                   bool away);
void board_z_velocity(int32_t velocity_um_s, uint16_t expiry_ms);
void board_send_motion_done(void);
void board_send_probe_result(void);
#if BOARD_HOMING
void board_z_home(uint8_t seq, uint32_t seek_um_s, uint32_t locate_um_s, uint32_t backoff_um,
                  uint32_t max_travel_um, uint16_t timeout_ms);
void board_send_home_result(void);
#endif

#endif /* DTHC_BOARD_INTERNAL_H */
