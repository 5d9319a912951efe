/* SPDX-License-Identifier: GPL-3.0-or-later */
/*
 * plant.c - the plate and the arc, in simulated time.
 *
 * Plate: its surface under the torch is plate_mm, plus warp_mm * sin(2 pi t / period)
 * while an arc is transferred (t: time since the transfer; the board knows nothing of XY,
 * so warp is modelled in time, and the surface at the start of a cut is the probed one).
 *
 * Arc: relay on -> PILOT (open-circuit voltage) -> after arc_ok_delay_ms, if the tip is
 * within transfer_max_mm of the plate, TRANSFERRED (ARC_OK active, voltage
 * cut_v + slope * (height - cut_height) + noise); a pilot that cannot transfer times out
 * after pilot_timeout_ms (NO_TRANSFER, 0 V); a transferred arc is LOST (ARC_OK inactive,
 * open-circuit voltage) above lose_above_mm; relay off -> OFF, 0 V.
 */
#include <math.h>

#include "host.h"

static const char *const arc_names[] = {"off", "pilot", "transferred", "lost", "no_transfer"};

static const char *const in_names[IN_COUNT] = {
	"arc_ok", "ohmic", "float", "breakaway", "thc_up", "thc_down", "estop",
	"z_limit_min", "z_limit_max",
};

const char *plant_arc_name(enum arc_state s) { return arc_names[s]; }

const char *input_name(int i) { return in_names[i]; }

static uint64_t next_u64(struct arc_model *a)
{
	/* xorshift64* */
	uint64_t x = a->rng;
	x ^= x >> 12;
	x ^= x << 25;
	x ^= x >> 27;
	a->rng = x;
	return x * 0x2545F4914F6CDD1DULL;
}

static double uniform01(struct arc_model *a)
{
	return ((double)(next_u64(a) >> 11) + 0.5) / 9007199254740992.0;
}

static double gaussian(struct arc_model *a)
{
	if (a->have_spare) {
		a->have_spare = 0;
		return a->spare;
	}
	double u = uniform01(a), v = uniform01(a);
	double r = sqrt(-2.0 * log(u));
	a->spare = r * sin(2.0 * M_PI * v);
	a->have_spare = 1;
	return r * cos(2.0 * M_PI * v);
}

void plant_seed(struct emu *e)
{
	e->arc.rng = e->seed * 0x9E3779B97F4A7C15ULL + 0x1234567ULL;
	if (!e->arc.rng)
		e->arc.rng = 1;
	e->arc.have_spare = 0;
}

double plant_surface_mm(const struct emu *e, uint64_t t_us)
{
	double s = e->p.plate_mm;
	if (e->arc.state == ARC_TRANSFERRED && e->p.warp_mm != 0.0 && e->p.warp_period_s > 0.0) {
		double t = (double)(t_us - e->arc.transfer_us) / 1e6;
		s += e->p.warp_mm * sin(2.0 * M_PI * t / e->p.warp_period_s);
	}
	return s;
}

static void set_state(struct emu *e, enum arc_state s)
{
	e->arc.state = s;
	record_event(e, "arc", "%s", arc_names[s]);
}

void plant_torch(struct emu *e, int on, uint64_t t_us)
{
	if (on) {
		if (e->arc.state != ARC_OFF)
			return;
		e->arc.on_us = t_us;
		set_state(e, ARC_PILOT);
	} else if (e->arc.state != ARC_OFF) {
		set_state(e, ARC_OFF);
	}
}

void plant_update(struct emu *e, uint64_t t_us)
{
	struct arc_model *a = &e->arc;
	double z = board_z_mm(e);
	if (a->state == ARC_PILOT) {
		double since_ms = (double)(t_us - a->on_us) / 1000.0;
		if (since_ms >= e->p.arc_ok_delay_ms && z - e->p.plate_mm <= e->p.transfer_max_mm) {
			a->transfer_us = t_us;
			set_state(e, ARC_TRANSFERRED);
		} else if (since_ms >= e->p.pilot_timeout_ms) {
			set_state(e, ARC_NO_TRANSFER);
		}
	} else if (a->state == ARC_TRANSFERRED) {
		if (z - plant_surface_mm(e, t_us) > e->p.lose_above_mm)
			set_state(e, ARC_LOST);
	}
}

/* The model's arc voltage now, without noise. */
double plant_arc_model_v(struct emu *e, uint64_t t_us)
{
	plant_update(e, t_us);
	double v;
	switch (e->arc.state) {
	case ARC_PILOT:
	case ARC_LOST:
		v = e->p.ocv_v;
		break;
	case ARC_TRANSFERRED: {
		double h = board_z_mm(e) - plant_surface_mm(e, t_us);
		v = e->p.cut_v + e->p.arc_slope_v_mm * (h - e->p.cut_height_mm);
		break;
	}
	default:
		v = 0.0;
	}
	return v;
}

/* One draw of the arc's noise (volts). */
double plant_noise(struct emu *e)
{
	return e->p.noise_v > 0.0 ? e->p.noise_v * gaussian(&e->arc) : 0.0;
}

/* The voltage one ADC conversion sees: the model plus a fresh noise draw. */
double plant_arc_voltage(struct emu *e, uint64_t t_us)
{
	double v = plant_arc_model_v(e, t_us);
	if (v > 0.0 && e->p.noise_v > 0.0)
		v += e->p.noise_v * gaussian(&e->arc);
	if (v < 0.0)
		v = 0.0;
	e->arc.last_v = v;
	return v;
}
