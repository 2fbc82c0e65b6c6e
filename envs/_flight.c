/* maptidal's per-control-period flight stack in C: what Simulation.step does in Python after the
 * commands are taken (envs/simulation.py), for many control periods in one call.
 *
 * Per period: each robot with an autopilot runs its ArduSub flight mode on its estimate
 * (controllers/flight_modes.py, pid.py, position_control.py), the mixer (controllers/mixing.py), the
 * thrust linearisation (controllers/thrusters.py) and the thrust curve into its actuators
 * (Simulation._drive); the physics steps; the odometry counts (Simulation._count_odometry); the IMU
 * biases walk and the sensors are read with noise (envs/sensors.py); each estimator folds the readings
 * in (controllers/estimation.py). The Python modules are the documentation and the reference this file
 * is tested against, operation for operation (tests/test_native_flight.py): change one, change both.
 *
 * Parameters and state travel as flat double arrays, one block per robot, whose fields are listed
 * below (X macros) and read by envs/native_flight.py through maptidal_flight_layout, so the two sides
 * cannot disagree about where a number lives. Noise comes in as standard normal draws made by the
 * simulation's numpy generator in the order the Python code draws them, so both paths see the same
 * noise. */
#include <math.h>
#include <pthread.h>
#include <string.h>
#include <time.h>
#include <mujoco/mujoco.h>

#define MAX_THR 8

/* ----- layout ----------------------------------------------------------------------------------- */
#define PARAM_FIELDS(X)                                                                                 \
  X(HAS_AUTOPILOT, 1) X(HAS_ESTIMATOR, 1) X(MODE, 1) X(N_THR, 1) X(CTRL_ADR, 1) X(ACT_ADR, 1)           \
  X(QPOS_ADR, 1) X(DOF_ADR, 1) X(BODY_ID, 1)                                                            \
  X(EN_IMU, 1) X(EN_DEPTH, 1) X(EN_DVL, 1) X(EN_COMPASS, 1)                                             \
  X(ADR_ACCEL, 1) X(ADR_GYRO, 1) X(ADR_MAG, 1) X(ADR_VELOCIMETER, 1) X(ADR_DEPTH_POS, 1) X(ADR_BEAM, 4) \
  X(ACCEL_SIGMA, 1) X(ACCEL_WALK, 1) X(GYRO_SIGMA, 1) X(GYRO_WALK, 1) X(DEPTH_SIGMA, 1)                 \
  X(DVL_SIGMA, 1) X(COMPASS_SIGMA_DEG, 1) X(DVL_LOW, 1) X(DVL_HIGH, 1) X(WATER_DEPTH, 1)                \
  X(MIX_6DOF, 1) X(MIX_COUPLING, 1) X(MIX_FACTORS, 6 * MAX_THR) X(MIX_REAR, MAX_THR)                    \
  X(PLANT_CURVE, 5) X(PLANT_PWM, 2) X(GAINS, MAX_THR) X(POWER, 4)                                       \
  X(LINEARISE, 1) X(LIN_CURVE, 5) X(LIN_PWM, 2)                                                         \
  X(SURFACE_Z, 1) X(DEPTH_SENSOR_POS, 3) X(DVL_POS, 3) X(TILT_K, 1) X(HEADING_K, 1)                     \
  X(HAS_MOTION_MODEL, 1) X(MM_INERTIA, 3) X(MM_LINEAR, 3) X(MM_QUADRATIC, 3) X(MM_BUOYANCY, 1)          \
  X(MM_LAG, 1)                                                                                          \
  X(BF_LINEAR, 1) X(BF_CURVE, 5) X(BF_PWM, 2) X(BF_MATRIX, 3 * MAX_THR)                                 \
  X(MAX_LEAN_DEG, 1) X(MAX_YAW_RATE_DEG_S, 1) X(RP_DZ, 1) X(YAW_DZ, 1) X(THR_DZ, 1) X(TRANS_DZ, 1)      \
  X(RATE_RP, 7) X(RATE_YAW, 7) X(POS_GAINS, 16) X(FC_SURFACE_Z, 1)

#define STATE_FIELDS(X)                                                                                 \
  X(PILOT, 6) X(FC_TIME, 1) X(HEADING, 1) X(HEADING_SET, 1) X(LAST_YAW_INPUT, 1) X(SATURATED, 3)        \
  X(RATE_PID, 15) X(DZ_INTEGRAL, 1) X(DZ_TARGET, 1) X(DZ_TARGET_SET, 1) X(DZ_CLIMB, 1) X(DZ_LIMIT, 1)   \
  X(DZ_VEL_ERROR, 1) X(XY_INTEGRAL, 2) X(XY_LAST_ERROR, 2) X(XY_LAST_SET, 1) X(HOLD_XY, 2)              \
  X(HOLD_SET, 1)                                                                                        \
  X(QUAT, 4) X(POSITION, 3) X(RPY, 3) X(VELOCITY, 3) X(RATES, 3) X(EST_TIME, 1) X(ACCEL_WORLD, 3)       \
  X(VELOCITY_WORLD, 3) X(THRUST_LAGGED, 3) X(MODELLED_LAST, 1) X(ACCEL_BIAS, 3) X(GYRO_BIAS, 3)         \
  X(ACCEL_MEAN, 3) X(ACCEL_MEAN_SET, 1)                                                                 \
  X(R_ACCEL, 3) X(R_GYRO, 3) X(R_ACCEL_MEAN, 3) X(R_DEPTH, 1) X(R_PRESSURE, 1) X(R_DVL_VELOCITY, 3)     \
  X(R_BEAMS, 4)                                                                                         \
  X(R_DVL_VALID, 1) X(R_HEADING, 1) X(R_FIELD, 3) X(R_THRUST, 3) X(R_THRUST_SET, 1)                     \
  X(OUTPUTS, MAX_THR) X(OUTPUTS_SET, 1) X(PATH, 1) X(ENERGY, 1) X(CONTACT_S, 1) X(VERTEX, 3)            \
  X(VERTEX_SET, 1)

#define ENUM_ITEM(name, size) P_##name##_INDEX,
enum { PARAM_FIELDS(ENUM_ITEM) N_PARAM_FIELDS };
#undef ENUM_ITEM
#define ENUM_ITEM(name, size) S_##name##_INDEX,
enum { STATE_FIELDS(ENUM_ITEM) N_STATE_FIELDS };
#undef ENUM_ITEM

#define SIZE_ITEM(name, size) size,
#define NAME_ITEM(name, size) #name,
static const int param_sizes[] = {PARAM_FIELDS(SIZE_ITEM)};
static const char* param_names[] = {PARAM_FIELDS(NAME_ITEM)};
static const int state_sizes[] = {STATE_FIELDS(SIZE_ITEM)};
static const char* state_names[] = {STATE_FIELDS(NAME_ITEM)};
static int param_offsets[N_PARAM_FIELDS + 1], state_offsets[N_STATE_FIELDS + 1], layout_ready = 0;

static void make_layout(void) {
  if (layout_ready) return;
  param_offsets[0] = state_offsets[0] = 0;
  for (int k = 0; k < N_PARAM_FIELDS; k++) param_offsets[k + 1] = param_offsets[k] + param_sizes[k];
  for (int k = 0; k < N_STATE_FIELDS; k++) state_offsets[k + 1] = state_offsets[k] + state_sizes[k];
  layout_ready = 1;
}

/* which: 0 parameters, 1 state. k < 0: returns the block's size in doubles; else the field's offset,
 * with its name and size, or -1 past the last field. */
int maptidal_flight_layout(int which, int k, const char** name, int* size) {
  make_layout();
  int n = which == 0 ? N_PARAM_FIELDS : N_STATE_FIELDS;
  const int* offsets = which == 0 ? param_offsets : state_offsets;
  if (k < 0) return offsets[n];
  if (k >= n) return -1;
  *name = which == 0 ? param_names[k] : state_names[k];
  *size = which == 0 ? param_sizes[k] : state_sizes[k];
  return offsets[k];
}

#define P(field) (p + param_offsets[P_##field##_INDEX])
#define S(field) (s + state_offsets[S_##field##_INDEX])

/* ----- small maths, as the Python writes it ---------------------------------------------------- */
static const double PI = 3.14159265358979323846;
static const double GRAVITY_EST = 9.81;     /* controllers/estimation.py STANDARD_GRAVITY */
static const double GRAVITY_POS = 9.80665;  /* controllers/position_control.py GRAVITY */
static const double ATMOSPHERE_PA = 101325.0, WATER_DENSITY = 1000.0;

static double clip(double x, double lo, double hi) { return x < lo ? lo : (x > hi ? hi : x); }
static double py_max(double a, double b) { return b > a ? b : a; } /* Python's max(a, b) */
static double py_min(double a, double b) { return b < a ? b : a; }
static double wrap_angle(double a) { return atan2(sin(a), cos(a)); }
static double py_mod(double x, double y) { /* Python's float % */
  double mod = fmod(x, y);
  if (mod != 0.0) {
    if ((y < 0) != (mod < 0)) mod += y;
  } else {
    mod = copysign(0.0, y);
  }
  return mod;
}
static double degrees(double x) { return x * (180.0 / PI); }
static double radians(double x) { return x * (PI / 180.0); }
static void cross3(const double a[3], const double b[3], double out[3]) {
  double o0 = a[1] * b[2] - a[2] * b[1], o1 = a[2] * b[0] - a[0] * b[2], o2 = a[0] * b[1] - a[1] * b[0];
  out[0] = o0, out[1] = o1, out[2] = o2;
}
static double dot3(const double a[3], const double b[3]) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

static void rotation_from_quaternion(const double q[4], double R[9]) {
  double w = q[0], x = q[1], y = q[2], z = q[3];
  R[0] = 1 - 2 * (y * y + z * z), R[1] = 2 * (x * y - w * z), R[2] = 2 * (x * z + w * y);
  R[3] = 2 * (x * y + w * z), R[4] = 1 - 2 * (x * x + z * z), R[5] = 2 * (y * z - w * x);
  R[6] = 2 * (x * z - w * y), R[7] = 2 * (y * z + w * x), R[8] = 1 - 2 * (x * x + y * y);
}
static void rotation_from_rpy(double roll, double pitch, double yaw, double R[9]) {
  double cr = cos(roll), sr = sin(roll), cp = cos(pitch), sp = sin(pitch), cy = cos(yaw), sy = sin(yaw);
  R[0] = cy * cp, R[1] = cy * sp * sr - sy * cr, R[2] = cy * sp * cr + sy * sr;
  R[3] = sy * cp, R[4] = sy * sp * sr + cy * cr, R[5] = sy * sp * cr - cy * sr;
  R[6] = -sp, R[7] = cp * sr, R[8] = cp * cr;
}
static void quaternion_from_rpy(double roll, double pitch, double yaw, double q[4]) {
  double cr = cos(roll / 2), sr = sin(roll / 2), cp = cos(pitch / 2), sp = sin(pitch / 2);
  double cy = cos(yaw / 2), sy = sin(yaw / 2);
  q[0] = cr * cp * cy + sr * sp * sy, q[1] = sr * cp * cy - cr * sp * sy;
  q[2] = cr * sp * cy + sr * cp * sy, q[3] = cr * cp * sy - sr * sp * cy;
}
static void rpy_from_rotation(const double R[9], double rpy[3]) {
  double pitch = -asin(py_max(-1.0, py_min(1.0, R[6])));
  rpy[0] = atan2(R[7], R[8]), rpy[1] = pitch, rpy[2] = atan2(R[3], R[0]);
}
static void rotate_quaternion(double q[4], const double v[3]) {
  double vx = v[0], vy = v[1], vz = v[2], angle = sqrt(vx * vx + vy * vy + vz * vz), c, sn;
  if (angle < 1e-12) {
    c = 1.0, sn = 0.5;
  } else {
    c = cos(angle / 2), sn = sin(angle / 2) / angle;
  }
  double dw = c, dx = sn * vx, dy = sn * vy, dz = sn * vz, w = q[0], x = q[1], y = q[2], z = q[3];
  double o[4] = {w * dw - x * dx - y * dy - z * dz, w * dx + x * dw + y * dz - z * dy,
                 w * dy - x * dz + y * dw + z * dx, w * dz + x * dy - y * dx + z * dw};
  double norm = sqrt(o[0] * o[0] + o[1] * o[1] + o[2] * o[2] + o[3] * o[3]);
  for (int k = 0; k < 4; k++) q[k] = o[k] / norm;
}
/* R @ v, rows as numpy sums them */
static void mat_vec(const double R[9], const double v[3], double out[3]) {
  for (int i = 0; i < 3; i++) out[i] = R[3 * i] * v[0] + R[3 * i + 1] * v[1] + R[3 * i + 2] * v[2];
}

/* ----- thrusters (controllers/thrusters.py) ---------------------------------------------------- */
/* curve: max_forward_n, max_reverse_n, deadband_us, forward_shape, reverse_shape; pwm: min, max */
static double command_to_pwm(double c, const double pwm[2]) {
  c = clip(c, -1.0, 1.0);
  return 1500.0 + c * (c > 0 ? pwm[1] - 1500.0 : 1500.0 - pwm[0]);
}
static double pwm_to_command(double pulse, const double pwm[2]) {
  double x = clip(pulse, pwm[0], pwm[1]) - 1500.0;
  return x > 0 ? x / (pwm[1] - 1500.0) : x / (1500.0 - pwm[0]);
}
static double thrust_n(double pulse, const double curve[5]) {
  double x = clip(pulse, 1100.0, 1900.0) - 1500.0, span = (1500.0 - 1100.0) - curve[2];
  double sc = clip((fabs(x) - curve[2]) / span, 0.0, 1.0);
  double k = x >= 0 ? curve[3] : curve[4], peak = x >= 0 ? curve[0] : -curve[1];
  return peak * sc * (sc + k) / (1.0 + k);
}
static double pulse_us(double f, const double curve[5]) {
  int forward = f >= 0;
  double peak = forward ? curve[0] : curve[1], k = forward ? curve[3] : curve[4];
  double y = clip(fabs(f) / peak, 0.0, 1.0) * (1.0 + k);
  double sc = (-k + sqrt(k * k + 4.0 * y)) / 2.0, span = (1500.0 - 1100.0) - curve[2];
  double offset = sc > 0 ? curve[2] + sc * span : 0.0;
  return 1500.0 + (forward ? offset : -offset);
}
static double linearise(double c, const double curve[5], const double pwm[2]) {
  c = clip(c, -1.0, 1.0);
  if (c == 0) return 0.0;
  double wanted = c >= 0 ? c * curve[0] : c * curve[1];
  return pwm_to_command(pulse_us(wanted, curve), pwm);
}

/* ----- the mixer (controllers/mixing.py): factors rows are motors, columns roll pitch yaw throttle
 * forward lateral (AP_Motors6DOF) ----------------------------------------------------------------- */
static void mix(const double* p, const double cmd[6], double* out) {
  int n = (int)*P(N_THR);
  const double* f = P(MIX_FACTORS);
  double pilot[6];
  for (int k = 0; k < 6; k++) pilot[k] = clip(cmd[k], -1.0, 1.0);
  double forward = pilot[0], lateral = pilot[1], throttle = pilot[2], roll = pilot[3], pitch = pilot[4],
         yaw = pilot[5];
  if (*P(MIX_6DOF) != 0.0) {
    double rpt[MAX_THR], yfl[MAX_THR], rpt_max = 1.0, yfl_max = 1.0;
    for (int i = 0; i < n; i++) {
      const double* r = f + 6 * i;
      /* pilot-axis order (surge, sway, heave, roll, pitch, yaw) as the Python's matrix product sums */
      rpt[i] = 0.0 * forward + 0.0 * lateral + r[3] * throttle + r[0] * roll + r[1] * pitch + 0.0 * yaw;
      yfl[i] = r[4] * forward + r[5] * lateral + 0.0 * throttle + 0.0 * roll + 0.0 * pitch + r[2] * yaw;
      rpt_max = py_max(rpt_max, fabs(rpt[i]));
      yfl_max = py_max(yfl_max, fabs(yfl[i]));
    }
    for (int i = 0; i < n; i++) out[i] = clip(rpt[i] / rpt_max + yfl[i] / yfl_max, -1.0, 1.0);
    return;
  }
  double limit = py_max(0.0, 1.0 - *P(MIX_COUPLING) * fabs(throttle));
  for (int i = 0; i < n; i++) {
    const double* r = f + 6 * i;
    double direction = P(MIX_REAR)[i], forward_motor = forward;
    if (forward != 0.0 && ((forward < 0) == (direction < 0)) && direction != 0) {
      forward_motor = clip(forward, -limit, limit);
    }
    double rpy = roll * r[0] + pitch * r[1] + yaw * r[2];
    double lin = throttle * r[3] + forward_motor * r[4] + lateral * r[5];
    out[i] = clip(rpy + lin, -1.0, 1.0);
  }
}

/* ----- AC_PID and sqrt_controller (controllers/pid.py) ------------------------------------------ */
static double lowpass_alpha(double dt, double cutoff_hz) {
  if (cutoff_hz <= 0.0) return 1.0;
  return dt / (dt + 1.0 / (2.0 * PI * cutoff_hz));
}
static double sqrt_controller(double error, double pgain, double limit, double dt) {
  double rate;
  if (limit <= 0.0) {
    rate = error * pgain;
  } else if (pgain == 0.0) {
    rate = error != 0.0 ? copysign(sqrt(2.0 * limit * fabs(error)), error) : 0.0;
  } else {
    double linear_distance = limit / (pgain * pgain);
    if (error > linear_distance) {
      rate = sqrt(2.0 * limit * (error - linear_distance / 2.0));
    } else if (error < -linear_distance) {
      rate = -sqrt(2.0 * limit * (-error - linear_distance / 2.0));
    } else {
      rate = error * pgain;
    }
  }
  if (dt > 0.0) return py_max(-fabs(error) / dt, py_min(fabs(error) / dt, rate));
  return rate;
}
static double inverse_sqrt_controller(double output, double pgain, double limit) {
  if (limit > 0.0 && pgain == 0.0) return output * output / (2.0 * limit);
  if (limit <= 0.0) return pgain != 0.0 ? output / pgain : 0.0;
  double linear_velocity = limit / pgain;
  if (fabs(output) < linear_velocity) return output / pgain;
  double linear_distance = limit / (pgain * pgain);
  return copysign(linear_distance / 2.0 + output * output / (2.0 * limit), output);
}
/* gains: kp ki kd imax fltt flte fltd; pid: integrator, reset_filter, target, error, derivative */
static double acpid_update(double* pid, const double* g, double target, double measurement, double dt,
                           int limit) {
  if (!(isfinite(target) && isfinite(measurement))) return 0.0;
  if (pid[1] != 0.0) {
    pid[1] = 0.0, pid[2] = target, pid[3] = target - measurement, pid[4] = 0.0;
  } else {
    double error_last = pid[3];
    pid[2] += lowpass_alpha(dt, g[4]) * (target - pid[2]);
    pid[3] += lowpass_alpha(dt, g[5]) * ((pid[2] - measurement) - pid[3]);
    double derivative = (pid[3] - error_last) / dt;
    pid[4] += lowpass_alpha(dt, g[6]) * (derivative - pid[4]);
  }
  if (g[1] != 0.0) {
    int shrinking = (pid[0] > 0.0 && 0.0 > pid[3]) || (pid[0] < 0.0 && 0.0 < pid[3]);
    if (!limit || shrinking) {
      pid[0] += pid[3] * g[1] * dt;
      pid[0] = py_max(-g[3], py_min(g[3], pid[0]));
    }
  } else {
    pid[0] = 0.0;
  }
  return pid[3] * g[0] + pid[0] + pid[4] * g[2];
}

/* ----- flight modes (controllers/flight_modes.py, position_control.py) --------------------------- */
enum { MODE_MANUAL = 0, MODE_STABILIZE = 1, MODE_ALT_HOLD = 2, MODE_POSHOLD = 3 };
static const double ATC_ANGLE_P = 6.0, HEADING_CAPTURE_DELAY_S = 0.25;
/* POS_GAINS order: pos_z_p vel_z_p acc_z_p acc_z_i acc_z_imax pilot_speed_up pilot_speed_down
 * pilot_accel_z surface_depth pos_xy_p vel_xy_p vel_xy_i vel_xy_d vel_xy_imax_cm_s2 angle_max_deg
 * max_speed_m_s */

static double dead_zone(double stick, double width) {
  double magnitude = fabs(stick) - width;
  if (magnitude <= 0.0) return 0.0;
  return copysign(py_min(1.0, magnitude / (1.0 - width)), stick);
}

static double velocity_world_axis(const double* s, int axis) {
  double R[9], v[3];
  rotation_from_rpy(S(RPY)[0], S(RPY)[1], S(RPY)[2], R);
  mat_vec(R, S(VELOCITY), v);
  return v[axis];
}

static double depth_cascade(const double* p, double* s, double z_target, double feedforward, double dt) {
  const double* g = P(POS_GAINS);
  double z = S(POSITION)[2], vz = velocity_world_axis(s, 2), error = z_target - z;
  double up = inverse_sqrt_controller(g[5], g[0], g[7]), down = inverse_sqrt_controller(g[6], g[0], g[7]);
  if (error > up || error < -down) {
    error = py_max(-down, py_min(up, error));
    if (*S(DZ_TARGET_SET) != 0.0) *S(DZ_TARGET) = z + error;
  }
  double climb = feedforward + sqrt_controller(error, g[0], g[7], dt);
  *S(DZ_VEL_ERROR) = climb - vz;
  double accel_target_cm = g[1] * *S(DZ_VEL_ERROR) * 100.0;
  double error_cm = accel_target_cm - S(ACCEL_WORLD)[2] * 100.0;
  *S(DZ_INTEGRAL) = clip(*S(DZ_INTEGRAL) + g[3] * error_cm * dt, -g[4], g[4]);
  double throttle = 0.001 * (g[2] * error_cm + *S(DZ_INTEGRAL));
  double heave = 2.0 * throttle;
  *S(DZ_LIMIT) = heave > 1.0 ? 1 : (heave < -1.0 ? -1 : 0);
  return clip(heave, -1.0, 1.0);
}

static double depth_from_climb_rate(const double* p, double* s, double climb_rate, double dt) {
  const double* g = P(POS_GAINS);
  double z = S(POSITION)[2];
  if (*S(DZ_TARGET_SET) == 0.0) {
    *S(DZ_TARGET) = z, *S(DZ_TARGET_SET) = 1.0;
    *S(DZ_CLIMB) = velocity_world_axis(s, 2);
  }
  double climb = py_max(-g[6], py_min(g[5], climb_rate)), limit = *S(DZ_LIMIT);
  double step = *S(DZ_CLIMB) * dt;
  if (!(step * limit > 0 && (*S(DZ_TARGET) - z) * limit > 0)) *S(DZ_TARGET) += step;
  double accel = g[7], change = py_max(-accel * dt, py_min(accel * dt, climb - *S(DZ_CLIMB)));
  if (!(change * limit > 0 && *S(DZ_VEL_ERROR) * limit > 0)) *S(DZ_CLIMB) += change;
  double ceiling = *P(FC_SURFACE_Z) - g[8];
  if (*S(DZ_TARGET) > ceiling) *S(DZ_TARGET) = ceiling, *S(DZ_CLIMB) = py_min(*S(DZ_CLIMB), 0.0);
  return depth_cascade(p, s, *S(DZ_TARGET), *S(DZ_CLIMB), dt);
}

static void position_hold(const double* p, double* s, double dt, double* forward, double* lateral) {
  const double* g = P(POS_GAINS);
  double R[9], vw[3];
  rotation_from_rpy(S(RPY)[0], S(RPY)[1], S(RPY)[2], R);
  mat_vec(R, S(VELOCITY), vw);
  double vt[2] = {g[9] * (S(HOLD_XY)[0] - S(POSITION)[0]), g[9] * (S(HOLD_XY)[1] - S(POSITION)[1])};
  double speed = sqrt(vt[0] * vt[0] + vt[1] * vt[1]);
  if (speed > g[15]) vt[0] *= g[15] / speed, vt[1] *= g[15] / speed;
  double err[2] = {(vt[0] - vw[0]) * 100.0, (vt[1] - vw[1]) * 100.0};
  double* integral = S(XY_INTEGRAL);
  integral[0] = integral[0] + g[11] * err[0] * dt, integral[1] = integral[1] + g[11] * err[1] * dt;
  double norm = sqrt(integral[0] * integral[0] + integral[1] * integral[1]);
  if (norm > g[13]) integral[0] *= g[13] / norm, integral[1] *= g[13] / norm;
  double deriv[2] = {0.0, 0.0};
  if (*S(XY_LAST_SET) != 0.0) {
    deriv[0] = (err[0] - S(XY_LAST_ERROR)[0]) / dt, deriv[1] = (err[1] - S(XY_LAST_ERROR)[1]) / dt;
  }
  S(XY_LAST_ERROR)[0] = err[0], S(XY_LAST_ERROR)[1] = err[1], *S(XY_LAST_SET) = 1.0;
  double ax = g[10] * err[0] + integral[0] + g[12] * deriv[0];
  double ay = g[10] * err[1] + integral[1] + g[12] * deriv[1];
  double c = cos(S(RPY)[2]), sn = sin(S(RPY)[2]);
  double forward_cm = c * ax + sn * ay, right_cm = sn * ax - c * ay, angle_max = radians(g[14]);
  *forward = clip(atan(forward_cm / (GRAVITY_POS * 100.0)) / angle_max, -1.0, 1.0);
  *lateral = clip(atan(right_cm / (GRAVITY_POS * 100.0)) / angle_max, -1.0, 1.0);
}

static double rate_loop(const double* p, double* s, int axis, double target, double measured, double dt) {
  const double* gains = axis == 2 ? P(RATE_YAW) : P(RATE_RP);
  double output = acpid_update(S(RATE_PID) + 5 * axis, gains, target, measured, dt, S(SATURATED)[axis] != 0.0);
  S(SATURATED)[axis] = fabs(output) >= 1.0 ? 1.0 : 0.0;
  return output;
}

static void flight_update(const double* p, double* s, double dt, double out[6]) {
  const double* pilot = S(PILOT);
  int mode = (int)*P(MODE);
  *S(FC_TIME) += dt;
  for (int k = 0; k < 6; k++) out[k] = pilot[k];
  if (mode == MODE_MANUAL) return;
  const double* rates = S(RATES);
  double angle_max = radians(*P(MAX_LEAN_DEG)), dz = *P(RP_DZ);
  double roll = dead_zone(pilot[3], dz) * angle_max, pitch = dead_zone(pilot[4], dz) * angle_max;
  double total = hypot(roll, pitch);
  if (total > angle_max) roll = roll * angle_max / total, pitch = pitch * angle_max / total;
  double targets[2] = {atan(cos(pitch) * tan(roll)), -pitch};
  double accel_max = radians(1100.0);
  for (int k = 0; k < 2; k++) {
    double error = wrap_angle(targets[k] - S(RPY)[k]);
    double rate_target = sqrt_controller(error, ATC_ANGLE_P, accel_max, dt);
    out[3 + k] = rate_loop(p, s, k, rate_target, rates[k], dt) * (k == 0 ? 1.0 : -1.0);
  }
  double yaw = S(RPY)[2];
  double yaw_rate_target = -dead_zone(pilot[5], *P(YAW_DZ)) * radians(*P(MAX_YAW_RATE_DEG_S));
  if (yaw_rate_target != 0.0) {
    *S(HEADING) = yaw, *S(HEADING_SET) = 1.0, *S(LAST_YAW_INPUT) = *S(FC_TIME);
  } else if (*S(FC_TIME) < *S(LAST_YAW_INPUT) + HEADING_CAPTURE_DELAY_S || *S(HEADING_SET) == 0.0) {
    *S(HEADING) = yaw, *S(HEADING_SET) = 1.0;
  } else {
    double error = wrap_angle(*S(HEADING) - yaw);
    yaw_rate_target = sqrt_controller(error, ATC_ANGLE_P, accel_max, dt);
  }
  out[5] = -rate_loop(p, s, 2, yaw_rate_target, rates[2], dt);
  if (mode == MODE_ALT_HOLD || mode == MODE_POSHOLD) {
    const double* g = P(POS_GAINS);
    double width = *P(THR_DZ), heave = pilot[2], climb = 0.0;
    if (heave > width) {
      climb = g[5] * (heave - width) / (1.0 - width);
    } else if (heave < -width) {
      climb = g[6] * (heave + width) / (1.0 - width);
    }
    out[2] = depth_from_climb_rate(p, s, climb, dt);
  }
  if (mode == MODE_POSHOLD) {
    double tdz = *P(TRANS_DZ);
    if (fabs(pilot[0]) > tdz || fabs(pilot[1]) > tdz || *S(HOLD_SET) == 0.0) {
      S(HOLD_XY)[0] = S(POSITION)[0], S(HOLD_XY)[1] = S(POSITION)[1], *S(HOLD_SET) = 1.0;
      S(XY_INTEGRAL)[0] = S(XY_INTEGRAL)[1] = 0.0, *S(XY_LAST_SET) = 0.0;
    } else {
      position_hold(p, s, dt, &out[0], &out[1]);
    }
  }
  for (int k = 0; k < 6; k++) out[k] = clip(out[k], -1.0, 1.0);
}

/* ----- driving the thrusters (Simulation._drive) ----------------------------------------------- */
static void drive(const double* p, double* s, mjData* d, const double* thrusters) {
  int n = (int)*P(N_THR), first = (int)*P(CTRL_ADR);
  const double* curve = P(PLANT_CURVE);
  for (int i = 0; i < n; i++) {
    S(OUTPUTS)[i] = thrusters[i];
    double force = thrust_n(command_to_pwm(thrusters[i], P(PLANT_PWM)), curve);
    double normalised = force >= 0 ? force / curve[0] : force / curve[1];
    d->ctrl[first + i] = normalised * P(GAINS)[i];
  }
  *S(OUTPUTS_SET) = 1.0;
}

/* ----- sensors (envs/sensors.py) --------------------------------------------------------------- */
static double heading_from_field(const double f[3], const double up[3]) {
  double ux = up[0], uy = up[1], uz = up[2], norm = sqrt(ux * ux + uy * uy + uz * uz);
  ux = ux / norm, uy = uy / norm, uz = uz / norm;
  double fx = f[0], fy = f[1], fz = f[2], along = fx * ux + fy * uy + fz * uz;
  double hx = fx - along * ux, hy = fy - along * uy, hz = fz - along * uz;
  double ax = 1.0 - ux * ux, ay = -ux * uy, az = -ux * uz;
  double lx = uy * az - uz * ay, ly = uz * ax - ux * az, lz = ux * ay - uy * ax;
  double angle = atan2(hx * lx + hy * ly + hz * lz, hx * ax + hy * ay + hz * az);
  return py_mod(degrees(angle), 360.0);
}

/* the readings into the state's R_ fields; returns how many draws it took */
static int read_sensors(const double* p, double* s, const mjData* d, const double* z) {
  const mjtNum* sd = d->sensordata;
  int used = 0;
  if (*P(EN_IMU) != 0.0) {
    int a = (int)*P(ADR_ACCEL), g = (int)*P(ADR_GYRO);
    for (int k = 0; k < 3; k++) S(R_ACCEL)[k] = (sd[a + k] + S(ACCEL_BIAS)[k]) + (0.0 + *P(ACCEL_SIGMA) * z[used + k]);
    used += 3;
    for (int k = 0; k < 3; k++) S(R_GYRO)[k] = (sd[g + k] + S(GYRO_BIAS)[k]) + (0.0 + *P(GYRO_SIGMA) * z[used + k]);
    /* the period's mean specific force, with the accelerometer's bias and its noise draw (RobotSensors.read) */
    const double* mean = *S(ACCEL_MEAN_SET) != 0.0 ? S(ACCEL_MEAN) : sd + a;
    for (int k = 0; k < 3; k++) {
      S(R_ACCEL_MEAN)[k] = (mean[k] + S(ACCEL_BIAS)[k]) + (0.0 + *P(ACCEL_SIGMA) * z[used - 3 + k]);
    }
    used += 3;
  }
  if (*P(EN_DEPTH) != 0.0) {
    double depth = (*P(WATER_DEPTH) - sd[(int)*P(ADR_DEPTH_POS) + 2]) + (0.0 + *P(DEPTH_SIGMA) * z[used++]);
    *S(R_DEPTH) = depth, *S(R_PRESSURE) = ATMOSPHERE_PA + WATER_DENSITY * 9.81 * depth;
  }
  if (*P(EN_DVL) != 0.0) {
    double low = *P(DVL_LOW), high = *P(DVL_HIGH);
    int valid = 1;
    for (int k = 0; k < 4; k++) {
      double r = sd[(int)P(ADR_BEAM)[k]];
      S(R_BEAMS)[k] = r;
      if (!(r >= low && r <= high)) valid = 0;
    }
    int v = (int)*P(ADR_VELOCIMETER);
    for (int k = 0; k < 3; k++) S(R_DVL_VELOCITY)[k] = sd[v + k] + (0.0 + *P(DVL_SIGMA) * z[used + k]);
    used += 3;
    *S(R_DVL_VALID) = valid;
  }
  if (*P(EN_COMPASS) != 0.0) {
    int f = (int)*P(ADR_MAG);
    for (int k = 0; k < 3; k++) S(R_FIELD)[k] = sd[f + k];
    const mjtNum* xmat = d->xmat + 9 * (int)*P(BODY_ID);
    double up[3] = {xmat[6], xmat[7], xmat[8]};
    double heading = heading_from_field(S(R_FIELD), up);
    *S(R_HEADING) = py_mod(heading + (0.0 + *P(COMPASS_SIGMA_DEG) * z[used++]), 360.0);
  }
  return used;
}

/* ----- the estimator (controllers/estimation.py DeadReckoning.update) -------------------------- */
static void body_force(const double* p, const double* outputs, double force[3]) {
  int n = (int)*P(N_THR);
  double thrust[MAX_THR];
  for (int i = 0; i < n; i++) {
    double c = outputs[i];
    if (*P(BF_LINEAR) != 0.0) {
      thrust[i] = c >= 0 ? c * P(BF_CURVE)[0] : c * P(BF_CURVE)[1];
    } else {
      thrust[i] = thrust_n(command_to_pwm(c, P(BF_PWM)), P(BF_CURVE));
    }
  }
  for (int j = 0; j < 3; j++) {
    double sum = 0.0;
    for (int i = 0; i < n; i++) sum += thrust[i] * P(BF_MATRIX)[j * MAX_THR + i];
    force[j] = sum;
  }
}

static void estimator_update(const double* p, double* s, double dt) {
  int imu = *P(EN_IMU) != 0.0, has_dvl = *P(EN_DVL) != 0.0, depth = *P(EN_DEPTH) != 0.0;
  int compass = *P(EN_COMPASS) != 0.0;
  double gyro[3], previous_velocity[3], R[9];
  for (int k = 0; k < 3; k++) gyro[k] = imu ? S(R_GYRO)[k] : S(RATES)[k];
  for (int k = 0; k < 3; k++) previous_velocity[k] = S(VELOCITY)[k];
  int dvl_valid = has_dvl && *S(R_DVL_VALID) != 0.0;
  int thrust = !dvl_valid;  /* Simulation._update_estimate adds the thrust reading without a DVL fix */
  int modelled = !dvl_valid && *P(HAS_MOTION_MODEL) != 0.0 && thrust;
  rotation_from_quaternion(S(QUAT), R);
  if (dvl_valid) {
    double lever[3];
    cross3(gyro, P(DVL_POS), lever);
    for (int k = 0; k < 3; k++) S(VELOCITY)[k] = S(R_DVL_VELOCITY)[k] - lever[k];
  } else if (modelled) {
    double up[3] = {R[6], R[7], R[8]}, force[3], momentum[3], turn[3], v[3];
    for (int k = 0; k < 3; k++) v[k] = S(VELOCITY)[k];
    double* lagged = S(THRUST_LAGGED);
    double lag = *P(MM_LAG);
    for (int k = 0; k < 3; k++) force[k] = S(R_THRUST)[k];
    if (lag > 0.0) {
      if (*S(MODELLED_LAST) != 0.0) {
        for (int k = 0; k < 3; k++) lagged[k] = lagged[k] + (1.0 - exp(-dt / lag)) * (force[k] - lagged[k]);
      } else {
        for (int k = 0; k < 3; k++) lagged[k] = force[k];
      }
      for (int k = 0; k < 3; k++) force[k] = lagged[k];
    }
    for (int k = 0; k < 3; k++) force[k] = force[k] + *P(MM_BUOYANCY) * up[k];
    for (int k = 0; k < 3; k++) momentum[k] = P(MM_INERTIA)[k] * v[k];
    cross3(gyro, momentum, turn);
    for (int k = 0; k < 3; k++) force[k] = force[k] - turn[k];
    for (int k = 0; k < 3; k++) {
      S(VELOCITY)[k] = (momentum[k] + dt * force[k]) /
                       (P(MM_INERTIA)[k] + dt * (P(MM_LINEAR)[k] + P(MM_QUADRATIC)[k] * fabs(v[k])));
    }
  }
  *S(MODELLED_LAST) = modelled;
  if (imu) {
    for (int k = 0; k < 3; k++) S(RATES)[k] = gyro[k];
    double turn[3] = {gyro[0] * dt, gyro[1] * dt, gyro[2] * dt};
    rotate_quaternion(S(QUAT), turn);
    rotation_from_quaternion(S(QUAT), R);
    double correction[3] = {0.0, 0.0, 0.0}, w_x_v[3], measured_up[3];
    cross3(gyro, S(VELOCITY), w_x_v);
    for (int k = 0; k < 3; k++) {
      double body_acceleration = (S(VELOCITY)[k] - previous_velocity[k]) / dt + w_x_v[k];
      measured_up[k] = S(R_ACCEL)[k] - body_acceleration;
    }
    double norm = sqrt(dot3(measured_up, measured_up));
    if (norm > 1e-6) {
      double k_tilt = py_min(*P(TILT_K), 1.0 / dt), unit[3], up[3] = {R[6], R[7], R[8]}, e[3];
      for (int k = 0; k < 3; k++) unit[k] = measured_up[k] / norm;
      cross3(unit, up, e);
      for (int k = 0; k < 3; k++) correction[k] = correction[k] + k_tilt * e[k];
    }
    if (compass) {
      double yaw = atan2(R[3], R[0]);
      double error = wrap_angle(-radians(*S(R_HEADING)) - yaw);
      double k_heading = py_min(*P(HEADING_K), 1.0 / dt);
      for (int k = 0; k < 3; k++) correction[k] = correction[k] + k_heading * error * R[6 + k];
    }
    if (correction[0] != 0.0 || correction[1] != 0.0 || correction[2] != 0.0) {
      double step[3] = {correction[0] * dt, correction[1] * dt, correction[2] * dt};
      rotate_quaternion(S(QUAT), step);
      rotation_from_quaternion(S(QUAT), R);
    }
  } else if (compass) {
    double rpy[3];
    rpy_from_rotation(R, rpy);
    double yaw = wrap_angle(-radians(*S(R_HEADING)));
    quaternion_from_rpy(rpy[0], rpy[1], yaw, S(QUAT));
    rotation_from_quaternion(S(QUAT), R);
  }
  rpy_from_rotation(R, S(RPY));
  if (imu) {
    double specific[3];
    mat_vec(R, S(R_ACCEL), specific);
    S(ACCEL_WORLD)[0] = specific[0] - 0.0, S(ACCEL_WORLD)[1] = specific[1] - 0.0;
    S(ACCEL_WORLD)[2] = specific[2] - GRAVITY_EST;
  }
  if (depth) {
    double sensor_height = R[6] * P(DEPTH_SENSOR_POS)[0] + R[7] * P(DEPTH_SENSOR_POS)[1] +
                           R[8] * P(DEPTH_SENSOR_POS)[2];
    S(POSITION)[2] = *P(SURFACE_Z) - *S(R_DEPTH) - sensor_height;
  }
  if (dvl_valid || modelled) mat_vec(R, S(VELOCITY), S(VELOCITY_WORLD));
  S(POSITION)[0] += S(VELOCITY_WORLD)[0] * dt;
  S(POSITION)[1] += S(VELOCITY_WORLD)[1] * dt;
  *S(EST_TIME) += dt;
}

/* ----- odometry (Simulation._count_odometry, Odometry.move_to) --------------------------------- */
static void count_odometry(const double* p, double* s, const mjData* d, double seconds, int touching,
                           double path_step) {
  if (touching) *S(CONTACT_S) += seconds;
  const mjtNum* q = d->qpos + (int)*P(QPOS_ADR);
  if (*S(VERTEX_SET) == 0.0) {
    for (int k = 0; k < 3; k++) S(VERTEX)[k] = q[k];
    *S(VERTEX_SET) = 1.0;
  } else {
    double dx = q[0] - S(VERTEX)[0], dy = q[1] - S(VERTEX)[1], dz = q[2] - S(VERTEX)[2];
    double step = sqrt(dx * dx + dy * dy + dz * dz);
    if (step >= path_step) {
      *S(PATH) += step;
      for (int k = 0; k < 3; k++) S(VERTEX)[k] = q[k];
    }
  }
  int n = (int)*P(N_THR), act = (int)*P(ACT_ADR);
  const double *curve = P(PLANT_CURVE), *pw = P(POWER);
  double total = 0.0;
  for (int i = 0; i < n; i++) {
    double x = d->act[act + i], thrust = x >= 0 ? x * curve[0] : x * curve[1];
    total += thrust >= 0 ? pw[0] * pow(thrust, pw[1]) : pw[2] * pow(-thrust, pw[3]);
  }
  *S(ENERGY) += total * seconds;
}

static int robot_touching(const mjModel* m, const mjData* d, int body) {
  for (int k = 0; k < d->ncon; k++) {
    if (m->geom_bodyid[d->contact[k].geom[0]] == body || m->geom_bodyid[d->contact[k].geom[1]] == body) {
      return 1;
    }
  }
  return 0;
}

static int bad_state_warnings(const mjData* d) {
  return d->warning[mjWARN_BADQPOS].number + d->warning[mjWARN_BADQVEL].number +
         d->warning[mjWARN_BADQACC].number;
}

/* substeps MuJoCo steps, the sensors computed in the last only (envs/simulation.py step_physics): nothing
 * reads them in between and they do not feed the dynamics, so the state and the final sensordata are
 * those of the full loop, bit for bit. The model's flags are restored; each model is flown by one thread. */
static void step_physics(mjModel* m, mjData* d, int substeps) {
  int flags = m->opt.disableflags;
  m->opt.disableflags = flags | mjDSBL_SENSOR;
  for (int k = 0; k < substeps - 1; k++) mj_step(m, d);
  m->opt.disableflags = flags;
  if (substeps > 0) mj_step(m, d);
}

/* Run n_periods control periods of n_robots robots (blocks of params and state, one per robot, in the
 * simulation's robot order), each period_s long (substeps physics steps). noise: the
 * standard normal draws, 6 per robot (the bias walks) then the reads of each estimating robot in
 * estimator_order (the Python's update order), per period; currents: NULL or 3 per period, the water current to set at
 * each period's start (current_slots: where each robot's current lives in userdata). per_period: 2 per
 * period per robot, the mean squared thruster output after the period's drive and whether the robot
 * touched anything at the period's end. Returns the number of periods run: fewer than n_periods when
 * the state went bad (NaN or a MuJoCo reset) in the next one. wall: the seconds spent in mj_step. */
int maptidal_flight_periods(const mjModel* m, mjData* d, const double* params, double* state,
                            int n_robots, const int* estimator_order, int n_estimators, int n_periods,
                            int substeps, double period_s, double path_step,
                            const double* noise, const double* currents, const int* current_slots,
                            double* per_period, double* wall) {
  make_layout();
  int pn = param_offsets[N_PARAM_FIELDS], sn = state_offsets[N_STATE_FIELDS];
  int used = 0;
  for (int t = 0; t < n_periods; t++) {
    if (currents) {
      for (int r = 0; r < n_robots; r++) {
        for (int k = 0; k < 3; k++) d->userdata[current_slots[r] + k] = currents[3 * t + k];
      }
    }
    for (int r = 0; r < n_robots; r++) {
      const double* p = params + r * pn;
      double* s = state + r * sn;
      if (*P(HAS_AUTOPILOT) == 0.0) continue;
      double command[6], thrusters[MAX_THR];
      flight_update(p, s, period_s, command);
      mix(p, command, thrusters);
      if (*P(LINEARISE) != 0.0) {
        for (int i = 0; i < (int)*P(N_THR); i++) thrusters[i] = linearise(thrusters[i], P(LIN_CURVE), P(LIN_PWM));
      }
      drive(p, s, d, thrusters);
    }
    /* each body's velocity at the period's start, held in ACCEL_MEAN until the mean replaces it */
    for (int r = 0; r < n_robots; r++) {
      const double* p = params + r * pn;
      double* s = state + r * sn;
      for (int k = 0; k < 3; k++) S(ACCEL_MEAN)[k] = d->qvel[(int)*P(DOF_ADR) + k];
    }
    int bad_before = bad_state_warnings(d);
    struct timespec start, stop;
    clock_gettime(CLOCK_MONOTONIC, &start);
    step_physics((mjModel*)m, d, substeps);
    clock_gettime(CLOCK_MONOTONIC, &stop);
    *wall += (stop.tv_sec - start.tv_sec) + 1e-9 * (stop.tv_nsec - start.tv_nsec);
    for (int r = 0; r < n_robots; r++) {  /* Simulation._period_specific_force */
      const double* p = params + r * pn;
      double* s = state + r * sn;
      const mjtNum* v = d->qvel + (int)*P(DOF_ADR);
      const mjtNum* xmat = d->xmat + 9 * (int)*P(BODY_ID);
      double w[3];
      for (int k = 0; k < 3; k++) w[k] = (v[k] - S(ACCEL_MEAN)[k]) / period_s - m->opt.gravity[k];
      for (int j = 0; j < 3; j++) S(ACCEL_MEAN)[j] = xmat[j] * w[0] + xmat[3 + j] * w[1] + xmat[6 + j] * w[2];
      *S(ACCEL_MEAN_SET) = 1.0;
    }
    for (int r = 0; r < n_robots; r++) {
      const double* p = params + r * pn;
      double* s = state + r * sn;
      int touching = d->ncon ? robot_touching(m, d, (int)*P(BODY_ID)) : 0;
      count_odometry(p, s, d, period_s, touching, path_step);
      double* out = per_period + 2 * (t * n_robots + r);
      int n = (int)*P(N_THR);
      double sq = 0.0;
      for (int i = 0; i < n; i++) sq += S(OUTPUTS)[i] * S(OUTPUTS)[i];
      out[0] = sq / n, out[1] = touching;
    }
    double root = sqrt(period_s);
    for (int r = 0; r < n_robots; r++) {
      const double* p = params + r * pn;
      double* s = state + r * sn;
      for (int k = 0; k < 3; k++) S(ACCEL_BIAS)[k] += 0.0 + *P(ACCEL_WALK) * root * noise[used + k];
      for (int k = 0; k < 3; k++) S(GYRO_BIAS)[k] += 0.0 + *P(GYRO_WALK) * root * noise[used + 3 + k];
      used += 6;
    }
    int finite = 1;
    for (int k = 0; k < m->nq && finite; k++) finite = isfinite(d->qpos[k]);
    for (int k = 0; k < m->nv && finite; k++) finite = isfinite(d->qvel[k]);
    if (bad_state_warnings(d) > bad_before || !finite) return t;
    for (int e = 0; e < n_estimators; e++) {
      int r = estimator_order[e];
      const double* p = params + r * pn;
      double* s = state + r * sn;
      if (*P(HAS_ESTIMATOR) == 0.0) continue;
      used += read_sensors(p, s, d, noise + used);
      int dvl_valid = *P(EN_DVL) != 0.0 && *S(R_DVL_VALID) != 0.0;
      *S(R_THRUST_SET) = !dvl_valid;
      if (!dvl_valid) {
        if (*S(OUTPUTS_SET) != 0.0) {
          body_force(p, S(OUTPUTS), S(R_THRUST));
        } else {
          S(R_THRUST)[0] = S(R_THRUST)[1] = S(R_THRUST)[2] = 0.0;
        }
      }
      estimator_update(p, s, period_s);
    }
  }
  return n_periods;
}

/* A batch of simulations with one robot each (the batched vector environment): maptidal_flight_periods
 * on each active one, with its own blocks, noise (draws_per_sim each), currents (periods x 3 where
 * blowing, else none) and per-period outputs (periods x 2). ran: the periods each flew. The simulations
 * are independent (their own mjModel and mjData), so n_threads threads share them out, each a
 * contiguous run of them; the results do not depend on the number of threads. */
typedef struct {
  const mjModel* const* models;
  mjData* const* datas;
  double *params, *state, *per_period, wall;
  const double *noise, *currents;
  const int *active, *blowing;
  int *ran, first_sim, last_sim, n_periods, substeps, draws_per_sim, current_slot;
  double period_s, path_step;
} BatchPart;

static void* fly_part(void* argument) {
  BatchPart* b = (BatchPart*)argument;
  int pn = param_offsets[N_PARAM_FIELDS], sn = state_offsets[N_STATE_FIELDS], first = 0;
  for (int i = b->first_sim; i < b->last_sim; i++) {
    if (!b->active[i]) continue;
    b->ran[i] = maptidal_flight_periods(
        b->models[i], b->datas[i], b->params + i * pn, b->state + i * sn, 1, &first, 1, b->n_periods,
        b->substeps, b->period_s, b->path_step, b->noise + i * b->draws_per_sim,
        b->blowing[i] ? b->currents + 3 * b->n_periods * i : NULL, &b->current_slot,
        b->per_period + 2 * b->n_periods * i, &b->wall);
  }
  return NULL;
}

#define MAX_BATCH_THREADS 256

void maptidal_flight_batch(int n_sims, const mjModel* const* models, mjData* const* datas, double* params,
                           double* state, const int* active, int n_periods, int substeps, double period_s,
                           double path_step, const double* noise, int draws_per_sim,
                           const double* currents, const int* blowing, int current_slot,
                           double* per_period, int* ran, double* wall, int n_threads) {
  make_layout();  /* before any thread reads the layout */
  if (n_threads > n_sims) n_threads = n_sims;
  if (n_threads > MAX_BATCH_THREADS) n_threads = MAX_BATCH_THREADS;
  if (n_threads < 1) n_threads = 1;
  BatchPart parts[MAX_BATCH_THREADS];
  pthread_t threads[MAX_BATCH_THREADS];
  int started[MAX_BATCH_THREADS];
  for (int t = 0; t < n_threads; t++) {
    BatchPart* b = &parts[t];
    b->models = models, b->datas = datas, b->params = params, b->state = state;
    b->per_period = per_period, b->wall = 0.0, b->noise = noise, b->currents = currents;
    b->active = active, b->blowing = blowing, b->ran = ran;
    b->first_sim = (int)((long)n_sims * t / n_threads), b->last_sim = (int)((long)n_sims * (t + 1) / n_threads);
    b->n_periods = n_periods, b->substeps = substeps, b->draws_per_sim = draws_per_sim;
    b->current_slot = current_slot, b->period_s = period_s, b->path_step = path_step;
    /* this thread flies the first part itself; a part whose thread cannot start is flown here too */
    started[t] = t > 0 && pthread_create(&threads[t], NULL, fly_part, b) == 0;
  }
  fly_part(&parts[0]);
  for (int t = 1; t < n_threads; t++) {
    if (started[t]) {
      pthread_join(threads[t], NULL);
    } else {
      fly_part(&parts[t]);
    }
  }
  for (int t = 0; t < n_threads; t++) *wall += parts[t].wall;
}
