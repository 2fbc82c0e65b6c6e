/* Fossen hydrodynamics and thrust for maptidal's BlueROV2s, as a MuJoCo passive-force
 * callback (mjcb_passive). envs/hydrodynamics.py holds the same model in numpy (the
 * fallback and the reference this file is tested against) and documents it; the
 * parameters travel in mjData.userdata, packed by envs/hydrodynamics.py:pack_userdata.
 *
 * Per robot, in the body frame (x fwd, y left, z up; origin at the CG, principal axes):
 *   tau_other = tau_thrust - C_RB(nu) nu - C_A(nu_r) nu_r - D(nu_r) nu_r + g_b + b_b
 *   (C_A only where the robot's added_mass_coriolis flag, slot SLOT_CORIOLIS, is set)
 *   nudot     = (tau_other - M_A c) / (M_RB + M_A)  (all diagonal), c = [w x (R^T v_current); 0]
 *   applied   = tau_thrust - C_A(nu_r) nu_r - D(nu_r) nu_r + b_b - M_A (nudot + c)
 * (M_A acts on the relative acceleration nudot_r = nudot + c of a constant current.)
 * MuJoCo itself supplies gravity and the rigid-body Coriolis terms, so the body
 * moves as (M_RB + M_A) nudot = tau_other: added mass from the current step's
 * forces, never from the last step's acceleration. */
#include <math.h>
#include <mujoco/mujoco.h>

#define MAGIC 4242.0
#define HEADER 4
#define BLOCK 86
#define SLOT_HULL 80     /* hull height (m), for the wet fraction */
#define SLOT_HULL_LENGTH 83 /* hull length and width (m): the hull's vertical extent at any attitude */
#define SLOT_HULL_WIDTH 84
#define SLOT_THRUST_FADE 82 /* half-width (m) of a thruster's fade-out at the water surface */
#define SLOT_CORIOLIS 81 /* 1: include C_A(nu_r) nu_r */
#define MAX_THRUSTERS 8

static void cross(const mjtNum a[3], const mjtNum b[3], mjtNum out[3]) {
  out[0] = a[1] * b[2] - a[2] * b[1];
  out[1] = a[2] * b[0] - a[0] * b[2];
  out[2] = a[0] * b[1] - a[1] * b[0];
}

void maptidal_hydro_passive(const mjModel* m, mjData* d) {
  if (m->nuserdata < HEADER || d->userdata[0] != MAGIC || d->userdata[2] == 0.0) return;
  int n = (int)d->userdata[1];
  if (m->nuserdata < HEADER + n * BLOCK) return;
  for (int k = 0; k < n; k++) {
    const mjtNum* p = d->userdata + HEADER + k * BLOCK;
    int body = (int)p[0], dof = (int)p[1], act = (int)p[2], nthr = (int)p[3];
    const mjtNum *added = p + 4, *dlin = p + 10, *dquad = p + 16;
    mjtNum buoyancy = p[22];
    const mjtNum *cb = p + 23, *current = p + 26;
    mjtNum fmax_fwd = p[29], fmax_rev = p[30];
    const mjtNum* thr = p + 31;
    int coriolis_added = p[SLOT_CORIOLIS] != 0.0;
    const mjtNum* R = d->xmat + 9 * body; /* body to world, row-major */
    const mjtNum* vw = d->qvel + dof;     /* world linear velocity of the CG */
    const mjtNum* w = d->qvel + dof + 3;  /* body angular velocity */

    mjtNum v[3], vr[3], zb[3], gb[3];
    for (int i = 0; i < 3; i++) {
      v[i] = R[i] * vw[0] + R[3 + i] * vw[1] + R[6 + i] * vw[2];
      vr[i] = v[i] - (R[i] * current[0] + R[3 + i] * current[1] + R[6 + i] * current[2]);
      zb[i] = R[6 + i]; /* world up in the body frame */
      gb[i] = m->body_mass[body] * (R[i] * m->opt.gravity[0] + R[3 + i] * m->opt.gravity[1] +
                                    R[6 + i] * m->opt.gravity[2]);
    }
    if (!(isfinite(v[0]) && isfinite(v[1]) && isfinite(v[2]) && isfinite(w[0]) && isfinite(w[1]) &&
          isfinite(w[2])))
      continue; /* leave NaN detection to the simulation's check */

    mjtNum thrust[6] = {0, 0, 0, 0, 0, 0};
    mjtNum surface_z = d->userdata[3], fade = p[SLOT_THRUST_FADE], cg_z = d->xipos[3 * body + 2];
    for (int t = 0; t < nthr && t < MAX_THRUSTERS; t++) {
      mjtNum a = d->act[act + t];
      mjtNum force = a >= 0 ? a * fmax_fwd : a * fmax_rev;
      const mjtNum *pos = thr + 6 * t, *dir = thr + 6 * t + 3;
      /* a propeller in air pushes nothing: fade linearly across the surface */
      mjtNum below = surface_z - (cg_z + R[6] * pos[0] + R[7] * pos[1] + R[8] * pos[2]);
      mjtNum wet_t = fade > 0 ? below / (2 * fade) + 0.5 : (below > 0 ? 1.0 : 0.0);
      force *= wet_t < 0 ? 0 : (wet_t > 1 ? 1 : wet_t);
      mjtNum f[3] = {force * dir[0], force * dir[1], force * dir[2]}, mom[3];
      cross(pos, f, mom);
      for (int i = 0; i < 3; i++) {
        thrust[i] += f[i];
        thrust[3 + i] += mom[i];
      }
    }

    mjtNum nur[6] = {vr[0], vr[1], vr[2], w[0], w[1], w[2]};
    mjtNum hydro[6]; /* -D(nu_r) nu_r - C_A(nu_r) nu_r + buoyancy */
    for (int i = 0; i < 6; i++) hydro[i] = -(dlin[i] + dquad[i] * fabs(nur[i])) * nur[i];
    mjtNum av[3] = {added[0] * vr[0], added[1] * vr[1], added[2] * vr[2]};
    mjtNum aw[3] = {added[3] * w[0], added[4] * w[1], added[5] * w[2]};
    mjtNum c1[3], c2[3], c3[3];
    cross(w, av, c1);  /* C_A nu_r, linear part:  w x (A_l v_r) */
    cross(vr, av, c2); /* C_A nu_r, angular part: v_r x (A_l v_r) + w x (A_r w) */
    cross(w, aw, c3);
    /* buoyancy fades out linearly as the hull leaves the water; the hull box spans cg_z +- h vertically,
     * h = (|R20| L + |R21| W + |R22| H) / 2 at its attitude */
    mjtNum surface = d->userdata[3];
    mjtNum half = 0.5 * (fabs(R[6]) * p[SLOT_HULL_LENGTH] + fabs(R[7]) * p[SLOT_HULL_WIDTH] + fabs(R[8]) * p[SLOT_HULL]);
    mjtNum wet = half > 0 ? (surface - (d->xipos[3 * body + 2] - half)) / (2 * half) : 1.0;
    buoyancy *= wet < 0 ? 0 : (wet > 1 ? 1 : wet);
    mjtNum fb[3] = {buoyancy * zb[0], buoyancy * zb[1], buoyancy * zb[2]}, mb[3];
    cross(cb, fb, mb);
    for (int i = 0; i < 3; i++) {
      hydro[i] += fb[i] - (coriolis_added ? c1[i] : 0.0);
      hydro[3 + i] += mb[i] - (coriolis_added ? c2[i] + c3[i] : 0.0);
    }

    /* rigid-body Coriolis for nudot: [m w x v, w x (I w)] */
    mjtNum mass = m->body_mass[body];
    const mjtNum* inertia = m->body_inertia + 3 * body;
    mjtNum iw[3] = {inertia[0] * w[0], inertia[1] * w[1], inertia[2] * w[2]}, crb_l[3], crb_a[3];
    cross(w, v, crb_l);
    cross(w, iw, crb_a);
    /* added mass acts on the relative acceleration: nudot_r = nudot + [w x (R^T v_c); 0] */
    mjtNum vc[3] = {v[0] - vr[0], v[1] - vr[1], v[2] - vr[2]}, turn[3];
    cross(w, vc, turn);
    mjtNum applied[6];
    for (int i = 0; i < 6; i++) {
      mjtNum rigid = i < 3 ? mass : inertia[i - 3];
      mjtNum current_turn = i < 3 ? turn[i] : 0.0;
      mjtNum other = thrust[i] + hydro[i] + (i < 3 ? gb[i] - mass * crb_l[i] : -crb_a[i - 3]) - added[i] * current_turn;
      mjtNum nudot = other / (rigid + added[i]);
      applied[i] = thrust[i] + hydro[i] - added[i] * (nudot + current_turn);
    }
    /* free joint: linear dofs take the world force, angular dofs the body torque */
    for (int i = 0; i < 3; i++) {
      d->qfrc_passive[dof + i] += R[3 * i] * applied[0] + R[3 * i + 1] * applied[1] + R[3 * i + 2] * applied[2];
      d->qfrc_passive[dof + 3 + i] += applied[3 + i];
    }
  }
}
