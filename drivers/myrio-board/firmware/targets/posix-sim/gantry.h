/*
 * The simulated axis behind posix-sim's hardware layer: a two-mass gantry.
 *
 *     m1 (cart, motor side) --- k, d --- m2 (load)
 *
 * The motor's torque tau acts on m1 as the force c (tau - tau_friction(v1)),
 * with Coulomb and viscous friction at the motor:
 *
 *     tau_friction = fc tanh(v1 / v_stick) + fv v1
 *
 * (the tanh makes the Coulomb step smooth below v_stick, far below any
 * speed the friction test holds). Its one flexible mode has the undamped
 * natural frequency sqrt(k (m1 + m2) / (m1 m2)) / 2 pi: what hilident must
 * find.
 */
#ifndef GANTRY_H
#define GANTRY_H

struct gantry_params {
	double m1;      /* cart, kg */
	double m2;      /* load, kg */
	double k;       /* coupling stiffness, N/m */
	double d;       /* coupling damping, N*s/m */
	double c;       /* torque-to-force constant, N/(N*m) */
	double fc;      /* Coulomb friction, N*m at the motor */
	double fv;      /* viscous friction, N*m per (m/s) */
	double v_stick; /* smoothing of the Coulomb step, m/s */
};

struct gantry {
	struct gantry_params p;
	double p1, v1, p2, v2; /* positions (m) and velocities (m/s) */
};

/* The posix-sim's axis. */
extern const struct gantry_params gantry_default;

void gantry_init(struct gantry *g, const struct gantry_params *p);

/* Advance by dt seconds with the motor torque held at torque_nm. */
void gantry_step(struct gantry *g, double torque_nm, double dt);

/* Undamped natural frequency of the flexible mode, Hz. */
double gantry_mode_hz(const struct gantry_params *p);

/* Its damping ratio (frictionless plant). */
double gantry_mode_damping(const struct gantry_params *p);

#endif
