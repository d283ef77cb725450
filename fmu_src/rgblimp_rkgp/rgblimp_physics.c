/* The RGBlimp's physics for the native RGBlimp FMUs: rgblimp_physics.h says what and why. */
#include <math.h>
#include <string.h>

#include "rgblimp_physics.h"

/* The states the dynamics do not read: the position x, y, z (greybox.h) */
#define N_UNREAD 3
#define YAW 5

static void cross(const double a[3], const double b[3], double out[3]) {
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

/* Body-to-earth rotation of the ZYX Euler angles, by rows (validation/vehicles/blimp_equations.py,
 * rotation_body_to_earth). */
static void rotation_body_to_earth(const double angles[3], double rotation[9]) {
    const double sf = sin(angles[0]), cf = cos(angles[0]);
    const double st = sin(angles[1]), ct = cos(angles[1]);
    const double sp = sin(angles[2]), cp = cos(angles[2]);
    rotation[0] = cp * ct, rotation[1] = -sp * cf + cp * st * sf, rotation[2] = sp * sf + cp * cf * st;
    rotation[3] = sp * ct, rotation[4] = cp * cf + sf * st * sp, rotation[5] = -cp * sf + st * sp * cf;
    rotation[6] = -st, rotation[7] = ct * sf, rotation[8] = ct * cf;
}

/* Aerodynamic force, N, and moment with the rate damping, N m, in body axes
 * (rgblimp_equations.py, wind_angles, rotation_wind_to_body, aerodynamic_force_and_moment). */
static void aerodynamics(const double v[3], const double w[3], double force[3], double moment[3]) {
    const double squares = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    const double alpha = atan2(v[2], v[0] + ZERO_SPEED_GUARD);
    const double beta = asin(v[1] / (sqrt(squares) + ZERO_SPEED_GUARD));
    const double qbar_area = 0.5 * AIR_DENSITY * squares * REFERENCE_AREA;
    const double alpha2 = alpha * alpha, beta2 = beta * beta;
    const double alpha_cross = alpha * fabs(alpha), beta_cross = beta * fabs(beta);
    const double drag = qbar_area * (C_D0 + C_D_ALPHA2 * alpha2 + C_D_BETA2 * beta2);
    const double side = qbar_area * (C_S0 + C_S_ALPHA2 * alpha2 + C_S_BETA * beta + C_S_BETA_ABS * beta_cross);
    const double lift = qbar_area * (C_L0 + C_L_ALPHA * alpha + C_L_BETA2 * beta2 + C_L_ALPHA_ABS * alpha_cross);
    const double coefficients[3] = {
        C_MX0 + C_MX_ALPHA * alpha + C_MX_BETA * beta,
        C_MY0 + C_MY_ALPHA * alpha + C_MY_BETA4 * pow(beta, 4.0) + C_MY_ALPHA_ABS * alpha_cross,
        C_MZ0 + C_MZ_ALPHA * alpha + C_MZ_BETA * beta + C_MZ_BETA_ABS * beta_cross};
    double wind_moment[3];
    for (int i = 0; i < 3; i++) wind_moment[i] = qbar_area * coefficients[i] + RATE_DAMPING[i] * w[i];
    /* wind to body axes: the first column is the unit airspeed direction */
    const double ca = cos(alpha), sa = sin(alpha), cb = cos(beta), sb = sin(beta);
    const double rotation[9] = {ca * cb, -ca * sb, -sa, sb, cb, 0.0, sa * cb, -sa * sb, ca};
    const double wind_force[3] = {-drag, side, -lift};
    for (int i = 0; i < 3; i++) {
        const double *row = rotation + 3 * i;
        force[i] = row[0] * wind_force[0] + row[1] * wind_force[1] + row[2] * wind_force[2];
        moment[i] = row[0] * wind_moment[0] + row[1] * wind_moment[1] + row[2] * wind_moment[2];
    }
}

/* Solve A x = b for A (6 x 6, by rows; overwritten) by Gaussian elimination with partial pivoting;
 * b becomes x. */
static void solve6(double A[36], double b[6]) {
    for (int k = 0; k < 6; k++) {
        int pivot = k;
        for (int i = k + 1; i < 6; i++)
            if (fabs(A[6 * i + k]) > fabs(A[6 * pivot + k])) pivot = i;
        if (pivot != k) {
            for (int j = 0; j < 6; j++) {
                const double t = A[6 * k + j];
                A[6 * k + j] = A[6 * pivot + j], A[6 * pivot + j] = t;
            }
            const double t = b[k];
            b[k] = b[pivot], b[pivot] = t;
        }
        for (int i = k + 1; i < 6; i++) {
            const double factor = A[6 * i + k] / A[6 * k + k];
            for (int j = k + 1; j < 6; j++) A[6 * i + j] -= factor * A[6 * k + j];
            b[i] -= factor * b[k];
        }
    }
    for (int k = 5; k >= 0; k--) {
        double sum = b[k];
        for (int j = k + 1; j < 6; j++) sum -= A[6 * k + j] * b[j];
        b[k] = sum / A[6 * k + k];
    }
}

/* U_dot, V_dot, W_dot, P_dot, Q_dot, R_dot (rgblimp_equations.py, body_accelerations; inputs with
 * the thrust factor applied). */
static void body_accelerations(const double s[N_STATES], const double u[N_INPUTS], double out[6]) {
    const double *angles = s + 3, *v = s + 6, *w = s + 9, *gondola = u + 2;
    /* thrust falling with airspeed (the draught field is not in the native FMUs: rgblimp_physics.h) */
    const double thrust_factor = 1.0 - THRUST_SPEED_LOSS * v[0];
    const double thrust_left = u[0] * thrust_factor, thrust_right = u[1] * thrust_factor;
    const double total_mass = HULL_MASS + GONDOLA_MASS;
    double l[3], skew[9], inertia[9];
    for (int i = 0; i < 3; i++) l[i] = HULL_MASS * HULL_CG[i] + GONDOLA_MASS * gondola[i];
    const double gondola_skew[9] = {0.0, -gondola[2], gondola[1], gondola[2], 0.0, -gondola[0],
                                    -gondola[1], gondola[0], 0.0};
    for (int i = 0; i < 9; i++) skew[i] = GONDOLA_MASS * gondola_skew[i];
    for (int i = 0; i < 3; i++) /* diag(I) - (m_b S(r_b)) S(r_b) */
        for (int j = 0; j < 3; j++) {
            double sum = 0.0;
            for (int k = 0; k < 3; k++) sum += skew[3 * i + k] * gondola_skew[3 * k + j];
            inertia[3 * i + j] = (i == j ? INERTIA[i] : 0.0) - sum;
        }
    const double down[3] = {-sin(angles[1]), cos(angles[1]) * sin(angles[0]), cos(angles[1]) * cos(angles[0])};
    double aero_force[3], aero_moment[3];
    aerodynamics(v, w, aero_force, aero_moment);
    const double thrust = thrust_left + thrust_right;
    const double thrust_moment[3] = {0.0, thrust * gondola[2],
                                     (thrust_left - thrust_right) * PROPELLER_ARM - THRUST_LINE_Y * thrust};

    double v_x_w[3], added_momentum[3], added_x_w[3], w_x_l[3], w_x_l_x_w[3];
    double inertia_w[3], inertia_w_x_w[3], added_x_v[3], added_angular[3], added_angular_x_w[3];
    double l_x_v_x_w[3], g_down[3], l_x_g_down[3], rhs[6], matrix[36];
    cross(v, w, v_x_w);
    for (int i = 0; i < 3; i++) added_momentum[i] = ADDED_MASS[i] * v[i];
    cross(added_momentum, w, added_x_w);
    cross(w, l, w_x_l);
    cross(w_x_l, w, w_x_l_x_w);
    for (int i = 0; i < 3; i++)
        inertia_w[i] = inertia[3 * i] * w[0] + inertia[3 * i + 1] * w[1] + inertia[3 * i + 2] * w[2];
    cross(inertia_w, w, inertia_w_x_w);
    cross(added_momentum, v, added_x_v);
    for (int i = 0; i < 3; i++) added_angular[i] = ADDED_INERTIA[i] * w[i];
    cross(added_angular, w, added_angular_x_w);
    cross(l, v_x_w, l_x_v_x_w);
    for (int i = 0; i < 3; i++) g_down[i] = GRAVITY * down[i];
    cross(l, g_down, l_x_g_down);
    for (int i = 0; i < 3; i++) {
        rhs[i] = total_mass * v_x_w[i] + added_x_w[i] + w_x_l_x_w[i]
                 + (total_mass - BUOYANCY_MASS) * GRAVITY * down[i] + aero_force[i] + (i == 0 ? thrust : 0.0);
        rhs[3 + i] = inertia_w_x_w[i] + added_x_v[i] + added_angular_x_w[i] + l_x_v_x_w[i] + l_x_g_down[i]
                     + aero_moment[i] + thrust_moment[i];
    }
    /* [[(m_t + A_v) I, -S(l)], [S(l), J + A_w]] */
    const double l_skew[9] = {0.0, -l[2], l[1], l[2], 0.0, -l[0], -l[1], l[0], 0.0};
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            matrix[6 * i + j] = i == j ? total_mass + ADDED_MASS[i] : 0.0;
            matrix[6 * i + 3 + j] = -l_skew[3 * i + j];
            matrix[6 * (3 + i) + j] = l_skew[3 * i + j];
            matrix[6 * (3 + i) + 3 + j] = inertia[3 * i + j] + (i == j ? ADDED_INERTIA[i] : 0.0);
        }
    solve6(matrix, rhs);
    memcpy(out, rhs, sizeof rhs);
}

/* d state / dt (rgblimp_equations.py, rgblimp_dynamics): position rates in earth axes, Euler
 * angle rates (blimp_equations.py, euler_rates) and the body accelerations. */
static void dynamics(const RGBlimpHeld *held, const double s[N_STATES], double out[N_STATES]) {
    const double *u = held->inputs;
    const double *angles = s + 3, *v = s + 6;
    double rotation[9];
    rotation_body_to_earth(angles, rotation);
    for (int i = 0; i < 3; i++) out[i] = rotation[3 * i] * v[0] + rotation[3 * i + 1] * v[1] + rotation[3 * i + 2] * v[2];
    const double sf = sin(angles[0]), cf = cos(angles[0]), ct = cos(angles[1]), tt = tan(angles[1]);
    const double p = s[9], q = s[10], r = s[11];
    out[3] = p + sf * tt * q + cf * tt * r;
    out[4] = cf * q - sf * r;
    out[5] = (sf * q + cf * r) / ct;
    body_accelerations(s, u, out + 6);
    if (held->extra != NULL) { /* rgblimp_dynamics's extra_acceleration */
        double extra[6];
        held->extra(held->extra_context, s, u, extra);
        for (int i = 0; i < 6; i++) out[6 + i] = out[6 + i] + extra[i];
    }
}

/* s with sign R(Theta)^T [WIND, 0] added to the body velocity (rgblimp_equations.py,
 * _with_velocity_offset). */
void rgblimp_add_wind_velocity(double s[N_STATES], double sign) {
    double rotation[9];
    rotation_body_to_earth(s + 3, rotation);
    const double wind[3] = {WIND[0], WIND[1], 0.0};
    for (int i = 0; i < 3; i++) {
        const double offset = rotation[i] * wind[0] + rotation[3 + i] * wind[1] + rotation[6 + i] * wind[2];
        s[6 + i] = s[6 + i] + sign * offset;
    }
}

/* a mod b with the sign of b, as Python's and numpy's % (numpy.remainder) compute it. */
static double remainder_floor(double a, double b) {
    double mod = fmod(a, b);
    if (mod != 0.0) {
        if ((b < 0.0) != (mod < 0.0)) mod += b;
    } else {
        mod = copysign(0.0, b);
    }
    return mod;
}


/* One sample of the identified model (rgblimp_equations.py, advance: the RK4 step, wrap_heading,
 * in the air mass's frame when there is wind) with yaw carried continuously (rgblimp_step.py,
 * carry_yaw). If unread is not NULL, unread[c] and unread[N_UNREAD + c] (c = x, y, z) are advanced
 * by the same increments as next[c] (greybox.h, GreyBoxPhysics). */
void rgblimp_step(const void *context, const double *start, double *next, double *unread) {
    const RGBlimpHeld *held = context;
    const int windy = WIND[0] != 0.0 || WIND[1] != 0.0;
    const double h = SAMPLE_TIME;
    double s[N_STATES], k1[N_STATES], k2[N_STATES], k3[N_STATES], k4[N_STATES], probe[N_STATES];
    memcpy(s, start, sizeof s);
    if (windy) rgblimp_add_wind_velocity(s, -1.0);
    dynamics(held, s, k1);
    for (int i = 0; i < N_STATES; i++) probe[i] = s[i] + 0.5 * h * k1[i];
    dynamics(held, probe, k2);
    for (int i = 0; i < N_STATES; i++) probe[i] = s[i] + 0.5 * h * k2[i];
    dynamics(held, probe, k3);
    for (int i = 0; i < N_STATES; i++) probe[i] = s[i] + h * k3[i];
    dynamics(held, probe, k4);
    for (int i = 0; i < N_STATES; i++) {
        const double increment = h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
        if (unread != NULL && i < N_UNREAD) {
            unread[i] = unread[i] + increment;
            unread[N_UNREAD + i] = unread[N_UNREAD + i] + increment;
        }
        next[i] = s[i] + increment;
    }
    /* wrap_heading: psi moved by one turn into [-pi, pi] */
    if (next[YAW] > PI) next[YAW] = next[YAW] - 2 * PI;
    else if (next[YAW] < -PI) next[YAW] = next[YAW] + 2 * PI;
    if (windy) {
        const double wind[3] = {WIND[0], WIND[1], 0.0};
        for (int c = 0; c < 3; c++) {
            next[c] = next[c] + SAMPLE_TIME * wind[c];
            if (unread != NULL) {
                unread[c] = unread[c] + SAMPLE_TIME * wind[c];
                unread[N_UNREAD + c] = unread[N_UNREAD + c] + SAMPLE_TIME * wind[c];
            }
        }
        rgblimp_add_wind_velocity(next, 1.0);
    }
    /* carry_yaw: the current yaw plus the wrapped yaw change */
    const double change = next[YAW] - start[YAW];
    next[YAW] = start[YAW] + remainder_floor(change + PI, 2 * PI) - PI;
}

void rgblimp_hold(RGBlimpHeld *held, const double inputs[N_INPUTS], ExtraAcceleration extra,
                  const void *extra_context) {
    for (int c = 0; c < N_INPUTS; c++) held->inputs[c] = c < 2 ? inputs[c] * THRUST_GAIN : inputs[c];
    held->extra = extra;
    held->extra_context = extra_context;
}
