/*
 * board_motion.c - Z: trapezoidal Z_MOVE, Z_PROBE with its stop on contact (Z_PROBE_AWAY:
 * up, stopped on the release of every sensor of its set), Z_VELOCITY with expiry, Z_STOP,
 * soft limits, Z_HOME on the home switch (protocol 1.3). Runs once per tick: the velocity
 * ramps towards what the mode wants by at most the acceleration limit per tick, and the
 * step generator gets bounds it never steps past (a move's target, a probe's end, the soft
 * limits, an active limit switch), so a late tick cannot overshoot them.
 */
#include "board_internal.h"

/* No division in the tick (a 32-bit one costs about 40 us on AVR): conversions by
 * multiplication with factors computed once. */
static int32_t um_per_step_q10;  /* 1000 * 1024 / steps_per_mm: z_um = boot + steps * k >> 10 */
static int32_t steps_per_um_q14; /* steps_per_mm * 16384 / 1000: rate = v * k >> 14 */
static int32_t min_steps;        /* the soft limits, in steps from the boot position */
static int32_t max_steps;
static int32_t target_steps;     /* the Z_MOVE target, or the probe's end, in steps */
static int32_t brake_full_um; /* distance beyond which braking never limits the speed */
static int32_t creep_um_s;    /* the slowest approach: Z stops from it within one tick */

/* Z idle at rest, and the step generator told so by the tick that stopped it: until a
 * command starts a motion, a tick has nothing to do for Z (about 25 us saved per tick). */
static bool z_at_rest;

static int32_t approach_um_s(int32_t d_um, int32_t feed);

/* Z at step count 0: the boot position, moved by homing (a build without it: fixed). */
#if BOARD_HOMING
#define Z_BASE_UM B.z_base_um
#else
#define Z_BASE_UM B.cfg->z_boot_um
#endif

static uint32_t isqrt32(uint32_t x)
{
    uint32_t r = 0;
    uint32_t bit = 1UL << 30;
    while (bit > x) {
        bit >>= 2;
    }
    while (bit) {
        if (x >= r + bit) {
            x -= r + bit;
            r = (r >> 1) + bit;
        } else {
            r >>= 1;
        }
        bit >>= 2;
    }
    return r;
}

/* The highest speed from which Z stops within d_um at the acceleration limit. */
static int32_t brake_um_s(int32_t d_um)
{
    const board_config_t *c = B.cfg;
    if (d_um <= 0) {
        return 0;
    }
    if (d_um >= brake_full_um) {
        return c->z_max_speed_um_s;
    }
    return (int32_t)isqrt32(2UL * (uint32_t)c->z_accel_um_s2 * (uint32_t)d_um);
}

static int32_t steps_of(int32_t um)
{
    return (um - Z_BASE_UM) * (int32_t)B.cfg->z_steps_per_mm / 1000;
}

static int32_t um_of_steps(int32_t steps)
{
    /* steps * k / 1024 rounded towards 0, by shifts: avr-gcc -Os calls the 32-bit division
     * (about 40 us) for a signed "/ 1024". */
    int32_t x = steps * um_per_step_q10;
    return Z_BASE_UM
           + (x < 0 ? -(int32_t)((uint32_t)-x >> 10) : (int32_t)((uint32_t)x >> 10));
}

int32_t board_z_um(void)
{
    return um_of_steps(hal_z_steps());
}

void board_z_update_dv(void)
{
    B.z_dv_um_s = (int32_t)((uint32_t)B.cfg->z_accel_um_s2 / 1000u * B.period_us / 1000u);
    if (B.z_dv_um_s < 1) {
        B.z_dv_um_s = 1;
    }
    creep_um_s = B.z_dv_um_s;
}

void board_z_init(void)
{
    const board_config_t *c = B.cfg;
    uint32_t vmax = (uint32_t)c->z_max_speed_um_s;
    brake_full_um = (int32_t)(vmax * vmax / (2u * (uint32_t)c->z_accel_um_s2)) + 1;
    um_per_step_q10 = (int32_t)(1024000UL / c->z_steps_per_mm);
    steps_per_um_q14 = (int32_t)(((uint32_t)c->z_steps_per_mm * 16384UL + 500u) / 1000u);
#if BOARD_HOMING
    B.z_base_um = c->z_boot_um; /* no homing yet: Z is taken where it stands at power-on */
#endif
    min_steps = steps_of(c->z_min_um);
    max_steps = steps_of(c->z_max_um);
    board_z_update_dv();
    hal_z_drive(0, min_steps, max_steps);
    z_at_rest = false;
}

bool board_z_busy(void)
{
    return B.z_mode != Z_IDLE || B.z_v_um_s != 0;
}

void board_send_motion_done(void)
{
    uint8_t *p = BOARD_SMALL_PAYLOAD_AT;
    dthc_motion_done_put_result(p, B.last_motion.result);
    dthc_motion_done_put_z_um(p, B.last_motion.z_um);
    dthc_motion_done_put_t_us(p, B.last_motion.t_us);
    board_send_small(DTHC_MSG_MOTION_DONE, B.last_motion.seq, DTHC_MOTION_DONE_SIZE);
}

void board_send_probe_result(void)
{
    uint8_t *p = BOARD_SMALL_PAYLOAD_AT;
    dthc_probe_result_put_result(p, B.last_probe.result);
    dthc_probe_result_put_sensor(p, B.last_probe.sensor);
    dthc_probe_result_put_contact_z_um(p, B.last_probe.contact_z_um);
    dthc_probe_result_put_stop_z_um(p, B.last_probe.stop_z_um);
    dthc_probe_result_put_t_us(p, B.last_probe.t_us);
    board_send_small(DTHC_MSG_PROBE_RESULT, B.last_probe.seq, DTHC_PROBE_RESULT_SIZE);
}

static void motion_done(uint8_t result, int32_t z_um)
{
    B.last_motion.valid = 1;
    B.last_motion.seq = B.move_seq;
    B.last_motion.result = result;
    B.last_motion.z_um = z_um;
    B.last_motion.t_us = hal_time_us();
    B.move_seq = 0;
    board_send_motion_done();
}

static void probe_done(int32_t z_um)
{
    B.last_probe.valid = 1;
    B.last_probe.seq = B.probe_seq;
    B.last_probe.result = B.probe_outcome;
    B.last_probe.sensor = B.probe_fired;
    B.last_probe.contact_z_um =
        B.probe_outcome == (B.probe_away ? DTHC_PROBE_RELEASED : DTHC_PROBE_CONTACT)
            ? B.probe_contact_um
            : z_um;
    B.last_probe.stop_z_um = z_um;
    B.last_probe.t_us = hal_time_us();
    B.probe_seq = 0;
    board_send_probe_result();
}

#if BOARD_HOMING
void board_send_home_result(void)
{
    uint8_t *p = BOARD_SMALL_PAYLOAD_AT;
    dthc_home_result_put_result(p, B.last_home.result);
    dthc_home_result_put_z_um(p, B.last_home.z_um);
    dthc_home_result_put_shift_um(p, B.last_home.shift_um);
    dthc_home_result_put_t_us(p, B.last_home.t_us);
    board_send_small(DTHC_MSG_HOME_RESULT, B.last_home.seq, DTHC_HOME_RESULT_SIZE);
}

static void home_done(int32_t z_um)
{
    B.last_home.valid = 1;
    B.last_home.seq = B.home_seq;
    B.last_home.result = B.home_outcome;
    B.last_home.z_um = z_um;
    B.last_home.shift_um = B.home_shift_um; /* 0 until the re-seek found the switch */
    B.last_home.t_us = hal_time_us();
    B.home_seq = 0;
    board_send_home_result();
}

/* um as steps, for lengths up to metres on any steps_per_mm (no 32-bit overflow). */
static int32_t length_steps(uint32_t um)
{
    uint32_t spm = B.cfg->z_steps_per_mm;
    if (um > 10000000UL) {
        um = 10000000UL; /* 10 m: more than any Z travels */
    }
    return (int32_t)((um / 1000u) * spm + (um % 1000u) * spm / 1000u);
}
#endif

/* End a running move, probe or homing early, reporting it (the caller decides how Z
 * stops). */
void board_z_end(uint8_t move_result, uint8_t probe_result)
{
    int32_t z = board_z_um();
    if (B.move_seq) {
        motion_done(move_result, z);
    }
    if (B.probe_seq) {
        B.probe_outcome = probe_result;
        probe_done(z);
    }
#if BOARD_HOMING
    if (B.home_seq) {
        B.home_outcome = DTHC_HOME_ABORTED;
        home_done(z);
    }
#endif
    if (B.z_mode != Z_IDLE) {
        B.z_mode = Z_STOPPING;
    }
}

/* Decelerate to a stop at the acceleration limit, then hold. */
void board_z_stop(void)
{
    if (B.z_mode != Z_IDLE || B.z_v_um_s != 0) {
        B.z_mode = Z_STOPPING;
    }
}

void board_z_move(uint8_t seq, int32_t target_um, uint32_t feed_um_s)
{
    board_z_end(DTHC_MOTION_SUPERSEDED, DTHC_PROBE_ABORTED);
    B.z_mode = Z_MOVE;
    B.z_target_um = target_um;
    target_steps = steps_of(target_um);
    B.z_feed_um_s = feed_um_s > (uint32_t)B.cfg->z_max_speed_um_s ? B.cfg->z_max_speed_um_s
                                                                  : (int32_t)feed_um_s;
    B.move_seq = seq;
}

void board_z_probe(uint8_t seq, uint32_t feed_um_s, uint32_t max_travel_um, uint16_t sensors,
                   bool away)
{
    int32_t z = board_z_um();
    int32_t travel = max_travel_um > 0x20000000UL ? 0x20000000L : (int32_t)max_travel_um;
    board_z_end(DTHC_MOTION_SUPERSEDED, DTHC_PROBE_ABORTED);
    B.z_mode = Z_PROBE;
    B.z_feed_um_s = feed_um_s > (uint32_t)B.cfg->z_max_speed_um_s ? B.cfg->z_max_speed_um_s
                                                                  : (int32_t)feed_um_s;
    B.probe_seq = seq;
    B.probe_away = away;
    B.probe_sensors = sensors;
    B.probe_end_um = away ? z + travel : z - travel;
    B.probe_to_limit = away ? B.probe_end_um > B.cfg->z_max_um : B.probe_end_um < B.cfg->z_min_um;
    if (B.probe_to_limit) {
        B.probe_end_um = away ? B.cfg->z_max_um : B.cfg->z_min_um;
    }
    target_steps = steps_of(B.probe_end_um);
    B.probe_fired = (uint16_t)(B.inputs & sensors);
    B.probe_outcome = BOARD_NO_OUTCOME;
    if ((B.probe_fired != 0) != away) { /* already in contact (away: released): zero travel */
        B.probe_outcome = away ? DTHC_PROBE_RELEASED : DTHC_PROBE_CONTACT;
        B.probe_contact_um = z;
    }
}

#if BOARD_HOMING
void board_z_home(uint8_t seq, uint32_t seek_um_s, uint32_t locate_um_s, uint32_t backoff_um,
                  uint32_t max_travel_um, uint16_t timeout_ms)
{
    int32_t steps = hal_z_steps();
    int32_t travel = length_steps(max_travel_um);
    uint32_t vmax = (uint32_t)B.cfg->z_max_speed_um_s;
    board_z_end(DTHC_MOTION_SUPERSEDED, DTHC_PROBE_ABORTED);
    B.homed = false; /* until this cycle finds the switch again */
    B.z_mode = Z_HOME;
    B.home_seq = seq;
    B.home_outcome = BOARD_NO_OUTCOME;
    B.home_seek_um_s = (int32_t)(seek_um_s > vmax ? vmax : seek_um_s);
    B.home_locate_um_s = (int32_t)(locate_um_s > vmax ? vmax : locate_um_s);
    B.home_backoff_um = (int32_t)backoff_um; /* within the soft limits: checked on receipt */
    B.home_lo_steps = steps - travel;
    B.home_hi_steps = steps + travel;
    B.home_shift_um = 0;
    B.home_deadline_us = hal_time_us() + (uint32_t)timeout_ms * 1000u;
    B.home_phase = (B.inputs & (1u << DTHC_INPUT_Z_LIMIT_MAX)) ? HOME_OFF_FIRST : HOME_SEEK;
}

/* One tick of Z_HOME: sets the speed Z wants and the step generator's bounds. */
static int32_t home_tick(int32_t steps, int32_t z, int32_t *lo, int32_t *hi)
{
    bool closed = (B.inputs & (1u << DTHC_INPUT_Z_LIMIT_MAX)) != 0;
    int32_t want = 0;
    /* Up, the soft limit does not hold until Z is found (the switch sits above it); down,
     * it does: a switch that never opens must not take the torch into the plate. */
    *lo = B.home_lo_steps > min_steps ? B.home_lo_steps : min_steps;
    *hi = B.home_hi_steps;
    if (B.home_outcome == BOARD_NO_OUTCOME && (int32_t)(B.now_us - B.home_deadline_us) >= 0) {
        B.home_outcome = DTHC_HOME_TIMEOUT;
    }
    if (B.home_outcome != BOARD_NO_OUTCOME) {
        if (B.z_v_um_s == 0) {
            B.z_mode = Z_IDLE;
            home_done(z);
        }
        return 0;
    }
    switch (B.home_phase) {
    case HOME_OFF_FIRST:
    case HOME_OFF:
        if (!closed) { /* released: on down by the backoff (one division, once) */
            target_steps = steps_of(z - B.home_backoff_um);
            if (target_steps < *lo) {
                target_steps = *lo;
            }
            B.home_phase++;
        } else if (steps <= *lo) {
            B.home_outcome = DTHC_HOME_NO_RELEASE;
        } else {
            want = -approach_um_s(z - um_of_steps(*lo), B.home_seek_um_s);
        }
        break;
    case HOME_CLEAR_FIRST:
    case HOME_CLEAR:
    case HOME_RETRACT:
        if (steps == target_steps) { /* from creep speed, as a Z_MOVE ends */
            B.z_v_um_s = 0;
            if (B.home_phase == HOME_RETRACT) {
                B.homed = true;
                B.home_outcome = DTHC_HOME_HOMED;
                B.z_mode = Z_IDLE;
                home_done(z);
            } else {
                B.home_phase++; /* CLEAR_FIRST -> SEEK, CLEAR -> LOCATE */
            }
        } else if (steps > target_steps) {
            *lo = target_steps;
            want = -approach_um_s(z - um_of_steps(target_steps), B.home_seek_um_s);
        } else {
            *hi = target_steps;
            want = approach_um_s(um_of_steps(target_steps) - z, B.home_seek_um_s);
        }
        break;
    case HOME_SEEK:
    case HOME_LOCATE:
        if (closed) {
            if (B.home_phase == HOME_LOCATE) {
                /* Found: this count is the home position from now on. */
                B.home_shift_um = B.cfg->z_home_um - z;
                B.z_base_um += B.home_shift_um;
                min_steps = steps_of(B.cfg->z_min_um);
                max_steps = steps_of(B.cfg->z_max_um);
                target_steps = steps_of(B.cfg->z_home_um - B.home_backoff_um);
                B.home_phase = HOME_RETRACT;
            } else {
                B.home_phase = HOME_OFF;
            }
        } else if (steps >= *hi) {
            B.home_outcome = DTHC_HOME_NOT_FOUND;
        } else {
            want = approach_um_s(um_of_steps(*hi) - z, B.home_phase == HOME_SEEK
                                                           ? B.home_seek_um_s
                                                           : B.home_locate_um_s);
        }
        break;
    default:
        break;
    }
    return want;
}
#endif

void board_z_velocity(int32_t velocity_um_s, uint16_t expiry_ms)
{
    int32_t vmax = B.cfg->z_max_speed_um_s;
    bool ending = B.move_seq || B.probe_seq; /* a command with a report: it ends here */
#if BOARD_HOMING
    ending = ending || B.home_seq;
#endif
    if (ending) {
        board_z_end(DTHC_MOTION_SUPERSEDED, DTHC_PROBE_ABORTED);
    }
    B.z_mode = Z_VELOCITY;
    B.z_feed_um_s = velocity_um_s > vmax ? vmax : velocity_um_s < -vmax ? -vmax : velocity_um_s;
    B.zvel_expiry_us = hal_time_us() + (uint32_t)expiry_ms * 1000u;
}

/* Speed towards an end d_um away: as fast as the feed allows while still able to stop
 * there (looking one tick and one step ahead: the position is known to a step), never so
 * slow that the last steps stall. */
static int32_t approach_um_s(int32_t d_um, int32_t feed)
{
    /* one tick's travel, / 2^20 standing in for / 10^6 (the step margin covers the 5 %) */
    int32_t ahead = ((B.z_v_um_s < 0 ? -B.z_v_um_s : B.z_v_um_s) * (int32_t)B.period_us) >> 20;
    int32_t v;
    if (d_um <= 0) {
        return 0;
    }
    v = brake_um_s(d_um - ahead - (um_per_step_q10 >> 10) - 1);
    if (v < creep_um_s) {
        v = creep_um_s;
    }
    return v > feed ? feed : v;
}

void board_z_tick(void)
{
    const board_config_t *c;
    int32_t steps;
    int32_t z;
    int32_t lo = min_steps; /* the step generator's bounds */
    int32_t hi = max_steps;
    int32_t want = 0;
    int32_t rate;
    int32_t v = B.z_v_um_s;
    int32_t dv = B.z_dv_um_s;

    if (B.z_mode == Z_IDLE && v == 0) {
        if (z_at_rest) {
            return;
        }
    } else {
        z_at_rest = false;
    }
    c = B.cfg;
    steps = hal_z_steps();
    z = um_of_steps(steps);
    switch (B.z_mode) {
    case Z_MOVE: {
        int32_t d = B.z_target_um - z;
        if (steps == target_steps) {
            v = 0; /* at the target, from at most creep speed: within one tick's change */
            B.z_mode = Z_IDLE;
            motion_done(DTHC_MOTION_REACHED, z);
        } else if (d > 0) {
            hi = target_steps;
            want = approach_um_s(d, B.z_feed_um_s);
        } else {
            lo = target_steps;
            want = -approach_um_s(-d, B.z_feed_um_s);
        }
        break;
    }
    case Z_PROBE: {
        /* Down until a sensor of the set is active (Z_PROBE), or up until every one is
         * released (Z_PROBE_AWAY): the same rules either way. */
        bool away = B.probe_away;
        int32_t to_end = away ? B.probe_end_um - z : z - B.probe_end_um;
        if (B.probe_outcome == BOARD_NO_OUTCOME) {
            uint16_t active = (uint16_t)(B.inputs & B.probe_sensors);
            if (active) {
                B.probe_fired = active; /* away: the last seen active, the last to let go */
            }
            if ((active != 0) != away) {
                /* The stop on contact (on the release): decided here, in the tick that
                 * read the input. */
                B.probe_outcome = away ? DTHC_PROBE_RELEASED : DTHC_PROBE_CONTACT;
                B.probe_contact_um = z;
            } else if (to_end <= 0) {
                B.probe_outcome = B.probe_to_limit ? DTHC_PROBE_LIMIT
                                  : away           ? DTHC_PROBE_NO_RELEASE
                                                   : DTHC_PROBE_NO_CONTACT;
            }
        }
        if (away) {
            hi = target_steps;
        } else {
            lo = target_steps;
        }
        if (B.probe_outcome == BOARD_NO_OUTCOME) {
            want = approach_um_s(to_end, B.z_feed_um_s);
            if (!away) {
                want = -want;
            }
        } else if (v == 0) {
            B.z_mode = Z_IDLE;
            probe_done(z);
        }
        break;
    }
    case Z_VELOCITY:
        if ((int32_t)(B.now_us - B.zvel_expiry_us) >= 0) {
            B.z_mode = Z_STOPPING; /* no newer Z_VELOCITY in time */
            break;
        }
        want = B.z_feed_um_s;
        if (want > 0) {
            if (steps >= max_steps) {
                board_latch(DTHC_FAULT_Z_LIMIT, 1);
                want = 0;
            } else {
                int32_t w = approach_um_s(c->z_max_um - z, want);
                want = w < want ? w : want;
            }
        } else if (want < 0) {
            if (steps <= min_steps) {
                board_latch(DTHC_FAULT_Z_LIMIT, 0);
                want = 0;
            } else {
                int32_t w = -approach_um_s(z - c->z_min_um, -want);
                want = w > want ? w : want;
            }
        }
        break;
    case Z_STOPPING:
        if (v == 0) {
            B.z_mode = Z_IDLE;
        }
        break;
#if BOARD_HOMING
    case Z_HOME:
        want = home_tick(steps, z, &lo, &hi);
        v = B.z_v_um_s; /* home_tick sets it to 0 where a step ends at its target */
        break;
#endif
    default:
        break;
    }
    if (B.z_mode == Z_STOPPING || B.z_mode == Z_IDLE) {
        want = 0;
    }
    if (v < want) {
        v = want - v > dv ? v + dv : want;
    } else if (v > want) {
        v = v - want > dv ? v - dv : want;
    }
    B.z_v_um_s = v;
    /* An active limit switch blocks motion towards it at once. */
    if (B.inputs & (1u << DTHC_INPUT_Z_LIMIT_MIN)) {
        lo = steps;
    }
    if (B.inputs & (1u << DTHC_INPUT_Z_LIMIT_MAX)) {
        hi = steps;
    }
    rate = ((v < 0 ? -v : v) * steps_per_um_q14) >> 14;
    hal_z_drive(v < 0 ? -rate : rate, lo, hi);
    z_at_rest = B.z_mode == Z_IDLE && v == 0;
}
