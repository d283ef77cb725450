/* The RGBlimp's physics for the native RGBlimp FMUs (rgblimp_model.c, the RKGP's;
 * ../rgblimp_hybrid/rgblimp_hybrid_model.c, the hybrid's): the identified RGBlimp model (Zhu, Cheng &
 * Zhang, IEEE RA-L 2024, arXiv 2404.18580, with flightgp's re-fitted coefficients, thrust factor and
 * steady wind) stepped by one classical RK4 step per 1/60 s sample, optionally with an extra body
 * acceleration in every stage. The same formulas, in the same order, as
 * validation/vehicles/rgblimp_equations.py (body_accelerations, aerodynamic_force_and_moment,
 * rgblimp_dynamics with its extra_acceleration, rk4_step, wrap_heading and advance: the rigid body
 * with the movable gondola mass about the centre of buoyancy, gravity, buoyancy, the aerodynamic
 * polynomials in angle of attack and sideslip with the optional cross-flow terms, rate damping, the
 * propeller thrusts with the optional loss with airspeed and thrust-line offset, an optional added
 * mass, and the steady wind by a change to the air mass's frame; the equations and their sources
 * are there; not the draught field that varies with position, whose parameters the builders
 * refuse unless zero, since the covariance step here relies on the dynamics not reading the
 * position) and validation/models/rgblimp_step.py (carry_yaw: yaw carried continuously).
 *
 * The model constants (every RGBlimpParameters field under its name in capitals, THRUST_GAIN, WIND,
 * SAMPLE_TIME, ZERO_SPEED_GUARD, PI, N_STATES = 12, N_INPUTS = 5) come from the FMU's model_config.h.
 *
 * The 6 x 6 system of the accelerations is solved by Gaussian elimination with partial pivoting
 * (the Python step multiplies by numpy.linalg.inv of the matrix, LAPACK's LU with partial
 * pivoting: the same factorisation, its operations in another order, so results agree to
 * rounding).
 */
#ifndef FLIGHTGP_RGBLIMP_PHYSICS_H
#define FLIGHTGP_RGBLIMP_PHYSICS_H

#include "model_config.h"

/* An extra body acceleration (m/s^2, rad/s^2) at the air-frame state s and the inputs u with the
 * thrust factor applied (rgblimp_dynamics's extra_acceleration). */
typedef void (*ExtraAcceleration)(const void *context, const double s[N_STATES], const double u[N_INPUTS],
                                  double out[6]);

/* What the physics sees over a step: the inputs with the thrusts times THRUST_GAIN
 * (rgblimp_equations.py, scaled_thrust; set by rgblimp_hold), and the extra acceleration (NULL:
 * none) with its context. */
typedef struct {
    double inputs[N_INPUTS];
    ExtraAcceleration extra;
    const void *extra_context;
} RGBlimpHeld;

/* The held inputs of the inputs as set (thrusts times THRUST_GAIN). */
void rgblimp_hold(RGBlimpHeld *held, const double inputs[N_INPUTS], ExtraAcceleration extra,
                  const void *extra_context);

/* One sample of the model (rgblimp_equations.py, advance: the RK4 step, wrap_heading, in the air
 * mass's frame when there is wind) with yaw carried continuously (rgblimp_step.py, carry_yaw);
 * context is an RGBlimpHeld. The dynamics do not read the position, and the wind's frame change
 * moves it by the same w h for every start: if unread is not NULL, unread[c] and unread[3 + c]
 * (c = x, y, z) are advanced by the same increments as next[c] (greybox.h, GreyBoxPhysics). */
void rgblimp_step(const void *context, const double *start, double *next, double *unread);

/* s with sign R(Theta)^T [WIND, 0] added to the body velocity (rgblimp_equations.py,
 * _with_velocity_offset). */
void rgblimp_add_wind_velocity(double s[N_STATES], double sign);

#endif
