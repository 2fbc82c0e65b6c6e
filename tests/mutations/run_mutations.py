"""Re-run the mutation lists of tests/README.md (M: physics, F: flight modes and estimator, V: done means
seen, L: localisation, S: sharing discoveries, T: the closed tank, I: interrupts, B: the batched
environment, N: the compiled flight stack, D: dense depth, P: planners, W: keeping clear of a teammate's
way, X: the box to inspect and retiring covered tasks, Y: what exploring counts and the survey's route,
Z: a lost robot standing down, U: time use, C: comparing batches, K: the IMU's period mean and the
thrusters' lag, A: the accelerometer's watch, H: a lost robot handing its view over): apply each
mutation to the source, run its group's tests, record which test fails first, and restore the
file. Every mutation must be killed.

    python tests/mutations/run_mutations.py            # all
    python tests/mutations/run_mutations.py M3 F7      # some

It edits files in place and restores them from memory afterwards (also on Ctrl-C); run it on a clean
tree.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TESTS = [
    "tests/test_fossen.py",
    "tests/test_physics.py",
    "tests/test_controllers.py",
    "tests/test_thrusters.py",
]

FLIGHT_TESTS = [
    "tests/test_estimation.py",
    "tests/test_ardusub_loops.py",
    "tests/test_feedback.py",
    "tests/test_model_aided.py",
    "tests/test_native_flight.py",
]
VERIFICATION_TESTS = ["tests/test_done_means_seen.py", "tests/test_mission.py"]
LOCALISATION_TESTS = ["tests/test_relocalisation.py", "tests/test_localisation_loop.py"]
SHARING_TESTS = ["tests/test_sharing.py", "tests/test_allocation.py"]
TANK_TESTS = ["tests/test_closed_tank.py", "tests/test_world_geometry.py"]
SIGNAL_TESTS = ["tests/test_signals.py"]
BATCHED_TESTS = ["tests/test_batched.py"]
NATIVE_TESTS = ["tests/test_native_flight.py"]
DENSE_TESTS = [
    "tests/test_dense_depth.py",
    "tests/test_map_discovery.py",
    "tests/test_loop_discovery.py",
    "tests/test_mission_perception.py",
]
PLANNER_TESTS = ["tests/test_planners.py"]
KEEP_CLEAR_TESTS = [
    "tests/test_clearance.py",
    "tests/test_allocation.py",
    "tests/test_mission.py::test_a_robot_keeps_clear_of_the_way_a_teammate_said_it_was_bound",
    "tests/test_mission.py::test_a_robot_keeps_clear_of_a_teammate_it_has_heard_from",
]
REGION_TESTS = [
    "tests/test_map_discovery.py",
    "tests/test_exploration.py",
    "tests/test_mission.py::test_the_box_a_team_is_sent_to_inspect",
    "tests/test_mission.py::test_a_robot_retires_the_task_its_review_found_covered_when_it_comes_to_it",
    "tests/test_loop_discovery.py::test_perception_reviews_the_path_against_the_views_taken_on_its_map",
    "tests/test_loop_discovery.py::test_a_frame_asks_for_the_reviews_the_mission_settings_ask_for",
]
EXPLORE_TESTS = [
    "tests/test_exploration.py",
    "tests/test_routes.py",
    "tests/test_mission.py::test_the_box_a_team_is_sent_to_inspect",
    "tests/test_loop_discovery.py::test_each_keyframes_dense_depth_maps_the_walls_where_they_are",
    "tests/test_loop_discovery.py::test_an_idle_robot_surveys_its_best_look_waits_for_a_teammate_and_then_has_explored",
    "tests/test_loop_discovery.py::test_with_survey_without_dvl_off_only_the_robots_with_a_dvl_survey",
    "tests/test_loop_discovery.py::test_each_robot_sweeps_as_wide_and_as_fast_as_its_settings_say",
    "tests/test_loop_discovery.py::test_a_robot_that_can_pitch_asks_for_pitched_looks_and_holds_the_pitch_through_the_sweep",
    "tests/test_loop_discovery.py::test_a_robot_that_has_explored_says_when_and_why",
    "tests/test_batch.py::test_why_the_robots_stopped_exploring_is_counted_per_planner_and_robot",
]
TIME_USE_TESTS = [
    "tests/test_time_use.py",
    "tests/test_mission.py::test_each_robots_time_is_told_by_occupation_period_by_period",
    "tests/test_loop_discovery.py::test_a_task_counts_for_the_survey_whose_frame_found_it",
]
STAND_DOWN_TESTS = [
    "tests/test_allocation.py::test_a_robot_standing_down_leaves_its_tasks_to_the_team_until_it_resumes",
    "tests/test_localisation_loop.py::test_a_robot_still_lost_after_its_recovery_stands_down_until_it_has_a_fix",
    "tests/test_localisation_loop.py::test_a_robot_lost_for_good_is_not_waited_for_and_the_ending_says_so",
    "tests/test_localisation_loop.py::test_without_standing_down_a_lost_robot_keeps_its_task",
]
COMPARE_TESTS = ["tests/test_batch_compare.py"]
LAG_TESTS = [
    "tests/test_imu_mean_and_thrust_lag.py",
    "tests/test_native_flight.py",
    "tests/test_batched.py",
]
PUSH_TESTS = ["tests/test_unmodelled_motion.py"]
SEARCH_MATCH_TESTS = [
    "tests/test_relocalisation.py::test_the_guided_match_is_the_literal_anchor_by_anchor_one",
    "tests/test_relocalisation.py::test_a_search_with_the_distances_worked_out_once_matches_as_keypoint_by_keypoint",
    "tests/test_relocalisation.py::test_locate_is_the_literal_ransac_hypothesis_by_hypothesis",
    "tests/test_relocalisation.py::test_locate_keeps_the_first_of_two_equally_good_hypotheses_as_the_literal_ransac_does",
]
HAND_OVER_TESTS = [
    "tests/test_localisation_loop.py::test_a_robot_lost_on_its_way_hands_the_view_to_a_teammate_with_nothing_left_to_do",
    "tests/test_localisation_loop.py::test_a_lost_robot_keeps_its_view_when_no_teammate_is_known_to_be_free",
]
TESTS_OF_GROUP = {
    "M": TESTS,
    "F": FLIGHT_TESTS,
    "V": VERIFICATION_TESTS,
    "L": LOCALISATION_TESTS,
    "S": SHARING_TESTS,
    "T": TANK_TESTS,
    "I": SIGNAL_TESTS,
    "B": BATCHED_TESTS,
    "N": NATIVE_TESTS,
    "D": DENSE_TESTS,
    "P": PLANNER_TESTS,
    "W": KEEP_CLEAR_TESTS,
    "X": REGION_TESTS,
    "Y": EXPLORE_TESTS,
    "Z": STAND_DOWN_TESTS,
    "U": TIME_USE_TESTS,
    "C": COMPARE_TESTS,
    "K": LAG_TESTS,
    "A": PUSH_TESTS,
    "H": HAND_OVER_TESTS,
    "G": SEARCH_MATCH_TESTS,
}

# id: (description, [(file, old, new), ...])
MUTATIONS: dict[str, tuple[str, list[tuple[str, str, str]]]] = {
    "M1": (
        "drop rigid-body Coriolis from the in-step solve",
        [("envs/_hydro.c", "(i < 3 ? gb[i] - mass * crb_l[i] : -crb_a[i - 3])", "(i < 3 ? gb[i] : 0.0)")],
    ),
    "M2": (
        "drop the added-mass Coriolis linear term -w x (A v_r)",
        [("envs/_hydro.c", "hydro[i] += fb[i] - (coriolis_added ? c1[i] : 0.0);", "hydro[i] += fb[i];")],
    ),
    "M3": (
        "flip the sign of the Munk moment v_r x (A v_r)",
        [
            (
                "envs/_hydro.c",
                "(coriolis_added ? c2[i] + c3[i] : 0.0)",
                "(coriolis_added ? -c2[i] + c3[i] : 0.0)",
            )
        ],
    ),
    "M4": (
        "divide the Heavy's heave added mass by 10 (vehicle file)",
        [
            (
                "assets/bluerov2/bluerov2.toml",
                "added_mass = [6.36, 7.12, 18.68,",
                "added_mass = [6.36, 7.12, 1.868,",
            )
        ],
    ),
    "M5": (
        "divide the Heavy's heave linear damping by 10 (vehicle file)",
        [
            (
                "assets/bluerov2/bluerov2.toml",
                "linear_damping = [13.7, 0.0, 33.0,",
                "linear_damping = [13.7, 0.0, 3.3,",
            )
        ],
    ),
    "M6": (
        "raise the Heavy's centre of buoyancy 10x (vehicle file)",
        [
            (
                "assets/bluerov2/bluerov2.toml",
                "centre_of_buoyancy = [0.0, 0.0, 0.049]",
                "centre_of_buoyancy = [0.0, 0.0, 0.49]",
            )
        ],
    ),
    "M7": (
        "wet fraction from the upright hull height alone (C and numpy)",
        [
            (
                "envs/_hydro.c",
                "mjtNum half = 0.5 * (fabs(R[6]) * p[SLOT_HULL_LENGTH] + fabs(R[7]) * p[SLOT_HULL_WIDTH]"
                " + fabs(R[8]) * p[SLOT_HULL]);",
                "mjtNum half = 0.5 * p[SLOT_HULL];",
            ),
            (
                "envs/hydrodynamics.py",
                "half = 0.5 * float(np.abs(np.asarray(rotation)[2]) @ np.asarray(hull_size, float))",
                "half = 0.5 * float(hull_size[2])",
            ),
        ],
    ),
    "M8": (
        "roll sign error in the Heavy's M5 mixing factors",
        [("controllers/mixing.py", "        [+1, -1, 0, -1, 0, 0],\n", "        [-1, -1, 0, -1, 0, 0],\n")],
    ),
    "M9": (
        "pitch sign error in the Heavy's M5 mixing factors",
        [("controllers/mixing.py", "        [+1, -1, 0, -1, 0, 0],\n", "        [+1, +1, 0, -1, 0, 0],\n")],
    ),
    "M10": (
        "roll sign error in the standard frame's M5 mixing factors",
        [("controllers/mixing.py", "        [+1, 0, 0, -1, 0, 0],\n", "        [-1, 0, 0, -1, 0, 0],\n")],
    ),
    "M11": (
        "added mass on the absolute instead of the relative acceleration in a current",
        [
            ("envs/_hydro.c", " - added[i] * current_turn;", ";"),
            ("envs/_hydro.c", "added[i] * (nudot + current_turn)", "added[i] * nudot"),
        ],
    ),
    "M12": (
        "T200 curve without its deadband",
        [
            (
                "controllers/thrusters.py",
                "s = ((np.abs(p) - self.deadband_us) / span).clip(0.0, 1.0)",
                "s = (np.abs(p) / 400.0).clip(0.0, 1.0)",
            )
        ],
    ),
    "M13": (
        "T200 curve with the forward and reverse shapes swapped",
        [
            (
                "controllers/thrusters.py",
                "k = np.where(p >= 0, self.forward_shape, self.reverse_shape)",
                "k = np.where(p >= 0, self.reverse_shape, self.forward_shape)",
            )
        ],
    ),
    "M14": (
        "the simulator drives the actuators with the raw commands (no curve)",
        [
            (
                "envs/simulation.py",
                "normalised = self._plants[robot].thruster.normalised_thrust(thrusters)",
                "normalised = thrusters",
            )
        ],
    ),
    "M15": (
        "the standard frame's surge damping left at Wu's uncalibrated value (vehicle file)",
        [
            (
                "assets/bluerov2/bluerov2.toml",
                "quadratic_damping = [54.72, 65.20, 111.34,",
                "quadratic_damping = [18.18, 65.20, 111.34,",
            )
        ],
    ),
    "F1": (
        "integrate the gyro's body rates as Euler-angle rates",
        [
            (
                "controllers/estimation.py",
                "self.quaternion = rotate_quaternion(self.quaternion, gyro * dt)",
                "self.quaternion = quaternion_from_rpy(*(np.array(rpy_from_rotation(rotation)) + gyro * dt))",
            )
        ],
    ),
    "F2": (
        "flip the sign of the estimator's gravity correction",
        [
            (
                "controllers/estimation.py",
                "cross3(measured_up / norm, rotation[2])",
                "cross3(rotation[2], measured_up / norm)",
            )
        ],
    ),
    "F3": (
        "flip the sign of the estimator's compass correction",
        [
            (
                "controllers/estimation.py",
                "correction += k * error * rotation[2]",
                "correction -= k * error * rotation[2]",
            )
        ],
    ),
    "F4": (
        "the depth target does not follow the climb (the old 'never release the captured depth')",
        [("controllers/position_control.py", "            self.target_z += step\n", "            pass\n")],
    ),
    "F5": (
        "the heading is captured once and not tracked while the yaw stick is deflected",
        [
            (
                "controllers/flight_modes.py",
                "self._heading, self._last_yaw_input_s = estimate.yaw, self.time_s",
                "self._last_yaw_input_s = self.time_s",
            ),
            (
                "controllers/flight_modes.py",
                "            self._heading = estimate.yaw  # brake to zero rate, still following the heading",
                "            self._heading = self._heading if self._heading is not None else estimate.yaw",
            ),
        ],
    ),
    "F6": (
        "the heading captured at the stick's release, without ArduSub's 250 ms brake",
        [("controllers/flight_modes.py", "HEADING_CAPTURE_DELAY_S = 0.25", "HEADING_CAPTURE_DELAY_S = 0.0")],
    ),
    "F7": (
        "our PID's anti-windup forced on (never integrates)",
        [
            (
                "controllers/pid.py",
                "        if abs(output) <= limit or (output > limit and e < 0)",
                "        if False and (output > limit and e < 0)",
            )
        ],
    ),
    "F8": (
        "our PID's anti-windup off (always integrates)",
        [
            (
                "controllers/pid.py",
                "        if abs(output) <= limit or (output > limit and e < 0)",
                "        if True or (output > limit and e < 0)",
            )
        ],
    ),
    "F9": (
        "reverse thrust linearised against the forward maximum",
        [
            (
                "controllers/thrusters.py",
                "c * curve.max_forward_n, c * curve.max_reverse_n)",
                "c * curve.max_forward_n, c * curve.max_forward_n)",
            )
        ],
    ),
    "F10": (
        "the old throttle dead zone, 0.05 of the stick",
        [
            (
                "controllers/flight_modes.py",
                "throttle_dead_zone: float = 100.0 / 500.0",
                "throttle_dead_zone: float = 0.05",
            )
        ],
    ),
    "F11": (
        "AC_PID differentiates the measurement instead of the error",
        [
            (
                "controllers/pid.py",
                "derivative = (self._error - error_last) / dt",
                "derivative = -(measurement - getattr(self, '_m', measurement)) / dt",
            ),
            (
                "controllers/pid.py",
                "        if g.ki != 0.0:\n",
                "        self._m = measurement\n        if g.ki != 0.0:\n",
            ),
        ],
    ),
    "F12": (
        "AC_PID's integrator ignores the limit flag",
        [("controllers/pid.py", "            if not limit or shrinking:", "            if True:")],
    ),
    "F13": (
        "the angle loop a plain P, without sqrt_controller's braking curve",
        [
            (
                "controllers/pid.py",
                "    if second_order_limit <= 0.0:\n        rate = error * p",
                "    if True:\n        rate = error * p",
            )
        ],
    ),
    "F14": (
        "MANUAL_CONTROL out of range dropped instead of clamped",
        [
            (
                "controllers/mavlink_wire.py",
                "    if not all(math.isfinite(v) for v in values):",
                "    if not manual_control_in_range(*values) or not all(math.isfinite(v) for v in values):",
            )
        ],
    ),
    "V1": (
        "the judgement of a capture ignores pitch (the angle of the horizontal directions only)",
        [
            (
                "maptidal/mission/verification.py",
                "    forward = np.asarray(camera_forward, float)\n"
                "    direction = np.asarray(task_direction, float)\n",
                "    forward = np.asarray(camera_forward, float) * [1, 1, 0]\n"
                "    direction = np.asarray(task_direction, float) * [1, 1, 0]\n",
            )
        ],
    ),
    "V2": (
        "unverified views are scored too",
        [
            (
                "maptidal/mission/run.py",
                "        if judged.verified:  # only views",
                "        if True:  # only views",
            )
        ],
    ),
    "V3": (
        "the robot's own check takes a level camera (it does not wait for the pitch)",
        [
            (
                "maptidal/mission/run.py",
                "                rotation[:, 0],\n                *robot.view,",
                "                np.r_[rotation[:2, 0], 0.0] / np.linalg.norm(rotation[:2, 0]),\n"
                "                *robot.view,",
            )
        ],
    ),
    "V4": (
        "the pitch stick is never sent (the robot flies level)",
        [
            (
                "maptidal/mission/run.py",
                "                    if reference.pitch:",
                "                    if False:",
            )
        ],
    ),
    "V5": (
        "a view beyond the vehicle's pitch is flown anyway, not declined",
        [
            (
                "maptidal/mission/verification.py",
                "        return None\n",
                "        return max(-cap, min(cap, pitch))\n",
            )
        ],
    ),
    "V6": (
        "a robot with nothing left to do gives way only as a busy one does",
        [
            (
                "maptidal/mission/run.py",
                "                agent.idle\n                or (",
                "                False\n                or (",
            )
        ],
    ),
    "V7": (
        "a busy robot waits on a teammate with nothing left to do",
        [("maptidal/mission/run.py", "not agent.peer_idle.get(peer, False)\n", "True\n")],
    ),
    "L1": (
        "the camera centre from rays with the projector's sign flipped (I + b b^T)",
        [("maptidal/perception/relocalisation.py", "np.eye(3)[None] - rays", "np.eye(3)[None] + rays")],
    ),
    "L2": (
        "a fix replaces the estimate whatever either's uncertainty (gain 1)",
        [
            (
                "maptidal/perception/odometry.py",
                "gain = self.sigma_m**2 / (self.sigma_m**2 + sigma_m**2)",
                "gain = 1.0",
            )
        ],
    ),
    "L3": (
        "no innovation gate",
        [
            (
                "maptidal/perception/relocalisation.py",
                "innovation > p.gate * math.hypot",
                "innovation > 1e9 * math.hypot",
            )
        ],
    ),
    "L4": (
        "no ratio test in the guided match",
        [("maptidal/perception/relocalisation.py", "first >= p.ratio * float", "first >= 1e9 * float")],
    ),
    "L5": (
        "surer anchors never take the place of unsure ones",
        [("maptidal/perception/relocalisation.py", "elif worse[close].all():", "elif False:")],
    ),
    "L6": (
        "a robot is lost only without fixes, never for its uncertainty",
        [("maptidal/mission/run.py", "lost = unfixed or robot.position_sigma_m > limit", "lost = unfixed")],
    ),
    "L7": (
        "a lost robot holds its reference instead of going home",
        [("maptidal/mission/run.py", "reference = robot.recovery.at(now - robot.lost_since_s)", "pass")],
    ),
    "L8": (
        "the DVL robot's visual step weighs 0.8 again",
        [("maptidal/perception/odometry.py", "visual_weight: float = 0.0025", "visual_weight: float = 0.8")],
    ),
    "L9": (
        "the front end never applies a fix",
        [
            (
                "maptidal/perception/frontend.py",
                "pose = self.odometry.correct(fix.centre, fix.sigma_m)",
                "pose = pose",
            )
        ],
    ),
    "L10": (
        "the drift rate never adapts to surprising fixes",
        [("maptidal/perception/odometry.py", "if normalised > 2.0:", "if False:")],
    ),
    "L11": (
        "the lost robot's search never widens past its first square",
        [
            (
                "maptidal/perception/relocalisation.py",
                "        self._ring = ring + 1 if ring < rings else 0",
                "        self._ring = 0",
            )
        ],
    ),
    "L12": (
        "a ring's fix bounded by the first search's reach",
        [
            (
                "maptidal/perception/relocalisation.py",
                "bound = outer if ring == 0 else math.sqrt(2.0) * outer + p.global_step_m",
                "bound = p.max_global_correction_m",
            )
        ],
    ),
    "L13": (
        "the found-again limit halved whatever made the robot lost",
        [
            (
                "maptidal/mission/run.py",
                'halved = robot.lost and robot.lost_why == "uncertain"',
                "halved = robot.lost",
            )
        ],
    ),
    "L14": (
        "a robot's losses on the way to a view never counted",
        [("maptidal/mission/run.py", '                robot.task_losses += robot.activity == "fly"\n', "")],
    ),
    "L15": (
        "a robot's losses counted against its view whatever it was doing",
        [
            (
                "maptidal/mission/run.py",
                '                robot.task_losses += robot.activity == "fly"\n',
                "                robot.task_losses += 1\n",
            )
        ],
    ),
    "L16": (
        "the count of losses not started afresh at a new view",
        [
            (
                "maptidal/mission/run.py",
                "            robot.within_since_s, robot.still_at, robot.task_losses = None, None, 0\n",
                "            robot.within_since_s, robot.still_at = None, None\n",
            )
        ],
    ),
    "L17": (
        "a dropout of the DVL never marks the robot unaided (session 33)",
        [
            (
                "maptidal/perception/odometry.py",
                "        if self.params.has_dvl and unaided_s > 0.0:\n            self.unaided = True\n",
                "        if self.params.has_dvl and unaided_s > 0.0:\n            pass\n",
            )
        ],
    ),
    "L18": (
        "an unaided robot's variance grows at the DVL's rate",
        [
            (
                "maptidal/perception/odometry.py",
                "base = self.params.drift_m2_s_dvl if self.dvl_aided else self.params.drift_m2_s_no_dvl",
                "base = self.params.drift_m2_s_dvl if self.params.has_dvl else self.params.drift_m2_s_no_dvl",
            )
        ],
    ),
    "L19": (
        "a fix does not end the robot's unaided spell",
        [
            (
                "maptidal/perception/odometry.py",
                "            self.unaided, self.drift_scale = False, 1.0\n",
                "            pass\n",
            )
        ],
    ),
    "L20": (
        "an unaided robot's refused fixes do not speed its drift up",
        [
            (
                "maptidal/perception/odometry.py",
                "max_drift_scale_dvl if self.dvl_aided else",
                "max_drift_scale_dvl if self.params.has_dvl else",
            )
        ],
    ),
    "L21": (
        "an unaided robot's visual steps weigh as with its DVL",
        [
            (
                "maptidal/perception/odometry.py",
                "        if self.dvl_aided:\n            return self.params.visual_weight\n",
                "        if self.params.has_dvl:\n            return self.params.visual_weight\n",
            )
        ],
    ),
    "L22": (
        "the mission never counts a DVL's dropouts",
        [
            (
                "maptidal/mission/run.py",
                "                    robot.dvl_out_s += elapsed_s\n",
                "                    pass\n",
            )
        ],
    ),
    "L23": (
        "the dropouts not handed to the front end",
        [
            (
                "maptidal/mission/run.py",
                "            dvl_out_s=robot.dvl_out_s,\n",
                "",
            )
        ],
    ),
    "L24": (
        "the dropouts counted again from frame to frame",
        [
            (
                "maptidal/mission/run.py",
                "        robot.dvl_out_s = 0.0\n",
                "",
            )
        ],
    ),
    "L25": (
        "the front end not handing the dropouts to its odometry",
        [
            (
                "maptidal/perception/frontend.py",
                "pose = self.odometry.update(pose, motion, dt, unaided_s, unmodelled_m)",
                "pose = self.odometry.update(pose, motion, dt, 0.0, unmodelled_m)",
            )
        ],
    ),
    "S1": (
        "a robot's own discoveries leave newest first",
        [
            (
                "maptidal/allocation/agent.py",
                "own = [slot for slot in lacking if self._keys[slot] >> 16 == self.index]",
                "own = [slot for slot in lacking if self._keys[slot] >> 16 == self.index][::-1]",
            )
        ],
    ),
    "S2": (
        "records after every bid entry (the version-2 priorities)",
        [
            (
                "maptidal/allocation/agent.py",
                "        items += [(None, slot) for slot in own]\n",
                "",
            ),
            (
                "maptidal/allocation/agent.py",
                "for slot in rest if slot not in on_path]\n",
                "for slot in rest if slot not in on_path]\n        items += [(None, slot) for slot in own]\n",
            ),
        ],
    ),
    "S3": (
        "relayed records before the robot's own",
        [
            (
                "maptidal/allocation/agent.py",
                "        items += [(None, slot) for slot in own]\n",
                "        items += [(None, slot) for slot in lacking"
                " if self._keys[slot] >> 16 != self.index]\n"
                "        items += [(None, slot) for slot in own]\n",
            )
        ],
    ),
    "S4": (
        "an overheard ack says nothing",
        [("maptidal/allocation/agent.py", "if robot != self.index and overheard is not None:", "if False:")],
    ),
    "S5": (
        "a run's offsets not sign-extended",
        [
            (
                "maptidal/allocation/messages.py",
                "offset -= (1 << _OFFSET_BITS) if offset > _OFFSET_LIMIT else 0",
                "offset -= 0",
            )
        ],
    ),
    "S6": (
        "a task no live robot holds counts as inherited",
        [("maptidal/mission/sharing.py", 'elif task["id"] in held_alive:', "elif True:")],
    ),
    "S7": (
        "a rediscovery's direction not checked",
        [
            (
                "maptidal/mission/sharing.py",
                'kind = "rediscovered" if bool(((near <= position_tolerance_m) & aligned).any())',
                'kind = "rediscovered" if bool((near <= position_tolerance_m).any())',
            )
        ],
    ),
    "S8": (
        "the idle bit never written on the wire",
        [
            (
                "maptidal/allocation/messages.py",
                "| (_IDLE if message.idle else 0)",
                "",
            )
        ],
    ),
    "T1": (
        "no far end wall",
        [
            (
                "maptidal/tank.py",
                "        if include_enclosure:\n            corners = np.array(",
                "        if False:\n            corners = np.array(",
            )
        ],
    ),
    "T2": (
        "the far end wall where the evaluated side walls end",
        [
            (
                "maptidal/tank.py",
                "math.radians(c.angled_angle_deg)) - c.side_length",
                "math.radians(c.angled_angle_deg)) - c.side_evaluated_length",
            )
        ],
    ),
    "T3": (
        "no room behind the glass",
        [("maptidal/tank.py", 'if kind == "pane" and include_enclosure:', "if False:")],
    ),
    "T4": (
        "the free-space check ignores the far end wall",
        [
            (
                "maptidal/evaluation/free_space.py",
                "water_side = positions[:, 0] > tank.far_x",
                "water_side = positions[:, 0] > -np.inf",
            )
        ],
    ),
    "T5": (
        "the far end wall drawn but not solid",
        [("envs/world.py", 'collide=kind != "room")', 'collide=kind not in ("room", "wall"))')],
    ),
    "I1": (
        "a signal raised at once, even during an import",
        [("maptidal/cli/interrupts.py", "        if at_a_bad_moment(frame):", "        if False:")],
    ),
    "I2": (
        "a signal raised while a child process starts",
        [("maptidal/cli/interrupts.py", "or _STARTING_A_CHILD in name", "or False")],
    ),
    "I3": (
        "an interrupted batch waits for its runs",
        [("maptidal/executors.py", "            process.terminate()\n", "            pass\n")],
    ),
    "I4": (
        "the handlers not put back",
        [
            (
                "maptidal/cli/interrupts.py",
                "            signal.signal(number, handler)  # type: ignore[arg-type]",
                "            pass",
            )
        ],
    ),
    "I5": (
        "an interrupted mission leaves its video to the garbage collector",
        [("maptidal/mission/run.py", "                self.video.abandon()", "                pass")],
    ),
    "I6": (
        "a signal's retry left pending after the command printed its line",
        [("maptidal/cli/interrupts.py", "        self.settle()\n", "        pass\n")],
    ),
    "I7": (
        "a retry still pending when the imports end is not cancelled before the command names itself",
        [
            (
                "maptidal/cli/__init__.py",
                "        try:\n            interrupts.settle()\n"
                "        except KeyboardInterrupt:\n            interrupts.settle()\n",
                "",
            )
        ],
    ),
    "B1": (
        "the batched rate loops' integrator ignores saturation",
        [("controllers/batched.py", "np.where(~limit | shrinking, grown, self.integrator)", "grown")],
    ),
    "B2": (
        "the batched pitch rate loop's output not negated",
        [
            (
                "controllers/batched.py",
                "outputs[:, 0], -outputs[:, 1], -outputs[:, 2]",
                "outputs[:, 0], outputs[:, 1], -outputs[:, 2]",
            )
        ],
    ),
    "B3": (
        "the batched estimator without its compass correction",
        [
            (
                "controllers/batched.py",
                "correction = correction + (heading_gain * error)[:, None] * rotation[:, 2]",
                "correction = correction",
            )
        ],
    ),
    "B4": (
        "the batched heading captured without the 250 ms delay",
        [
            (
                "controllers/batched.py",
                "(self.time_s < self.last_yaw_input_s + HEADING_CAPTURE_DELAY_S)",
                "(self.time_s < self.last_yaw_input_s)",
            )
        ],
    ),
    "B5": (
        "the batched estimator always on the motion model",
        [
            (
                "controllers/batched.py",
                "velocity = np.where(dvl_valid[:, None], velocity, modelled)",
                "velocity = modelled",
            )
        ],
    ),
    "B6": (
        "the batch's accelerometer bias does not walk",
        [("envs/gym/batched.py", "        self.accel_bias += noise[:, 0:3]\n", "")],
    ),
    "B7": (
        "the batch's GoToPose reward without the contact cost",
        [
            (
                "envs/gym/batched.py",
                "rewards = rewards - (0.05 * energy + contact_cost) + within",
                "rewards = rewards - (0.05 * energy) + within",
            )
        ],
    ),
    "B8": (
        "the batch's gyro noise taken from the accelerometer's normals",
        [("envs/gym/batched.py", "self.gyro_bias + noise[:, 9:12]", "self.gyro_bias + noise[:, 6:9]")],
    ),
    "B9": (
        "an autoresetting row keeps its last step's info",
        [("envs/gym/batched.py", "infos = _only_rows(infos, active)", "pass")],
    ),
    "B10": (
        "a row waiting on its reset keeps its last step's contacts (compiled batch)",
        [("envs/gym/batched.py", "        per_period[active == 0] = 0.0", "        pass")],
    ),
    "B11": (
        "a reset row's readings left as the packed state has them (zeros; compiled batch)",
        [
            (
                "envs/native_flight.py",
                '            put("R_ACCEL", readings["imu"]["accel"])',
                "            pass",
            )
        ],
    ),
    "N1": (
        "the motion model without its Coriolis term",
        [("envs/_flight.c", "force[k] = force[k] - turn[k];", "force[k] = force[k];")],
    ),
    "N2": (
        "the yaw rate loop's output not negated",
        [("envs/_flight.c", "out[5] = -rate_loop(p, s, 2", "out[5] = rate_loop(p, s, 2")],
    ),
    "N3": (
        "the vectored-6DOF mixer without its roll-pitch-throttle normalisation",
        [
            (
                "envs/_flight.c",
                "out[i] = clip(rpt[i] / rpt_max + yfl[i] / yfl_max",
                "out[i] = clip(rpt[i] + yfl[i] / yfl_max",
            )
        ],
    ),
    "N4": (
        "the compass noise subtracted",
        [
            (
                "envs/_flight.c",
                "py_mod(heading + (0.0 + *P(COMPASS_SIGMA_DEG)",
                "py_mod(heading - (0.0 + *P(COMPASS_SIGMA_DEG)",
            )
        ],
    ),
    "N5": (
        "the forward power law's exponent taken from reverse",
        [("envs/_flight.c", "pw[0] * pow(thrust, pw[1])", "pw[0] * pow(thrust, pw[3])")],
    ),
    "N6": (
        "the depth hold never sees its throttle saturated",
        [
            (
                "envs/_flight.c",
                "*S(DZ_LIMIT) = heave > 1.0 ? 1 : (heave < -1.0 ? -1 : 0);",
                "*S(DZ_LIMIT) = 0;",
            )
        ],
    ),
    "N7": (
        "the horizontal hold's integrator bound ten times too wide",
        [("envs/_flight.c", "if (norm > g[13]) integral[0]", "if (norm > 10 * g[13]) integral[0]")],
    ),
    "N8": (
        "the horizontal hold's derivative of a sum",
        [
            (
                "envs/_flight.c",
                "deriv[0] = (err[0] - S(XY_LAST_ERROR)[0]) / dt",
                "deriv[0] = (err[0] + S(XY_LAST_ERROR)[0]) / dt",
            )
        ],
    ),
    "N9": (
        "the depth target allowed 1 m above the surface margin",
        [("envs/_flight.c", "if (*S(DZ_TARGET) > ceiling)", "if (*S(DZ_TARGET) > ceiling + 1.0)")],
    ),
    "N10": (
        "the depth sensor's lever arm added",
        [
            (
                "envs/_flight.c",
                "S(POSITION)[2] = *P(SURFACE_Z) - *S(R_DEPTH) - sensor_height;",
                "S(POSITION)[2] = *P(SURFACE_Z) - *S(R_DEPTH) + sensor_height;",
            )
        ],
    ),
    "N11": (
        "the gyro bias does not walk",
        [
            (
                "envs/_flight.c",
                "S(GYRO_BIAS)[k] += 0.0 + *P(GYRO_WALK) * root",
                "S(GYRO_BIAS)[k] += 0.0 * *P(GYRO_WALK) * root",
            )
        ],
    ),
    "N12": (
        "thrust never linearised",
        [("envs/_flight.c", "if (*P(LINEARISE) != 0.0) {", "if (0) {")],
    ),
    "N13": (
        "the vectored mixer without forward-vertical coupling",
        [("envs/_flight.c", "forward_motor = clip(forward, -limit, limit);", "forward_motor = forward;")],
    ),
    "N14": (
        "the DVL's lever arm left in its velocity",
        [
            (
                "envs/_flight.c",
                "S(VELOCITY)[k] = S(R_DVL_VELOCITY)[k] - lever[k];",
                "S(VELOCITY)[k] = S(R_DVL_VELOCITY)[k];",
            )
        ],
    ),
    "N15": (
        "the estimator without gravity's tilt correction",
        [
            (
                "envs/_flight.c",
                "correction[k] = correction[k] + k_tilt * e[k];",
                "correction[k] = correction[k];",
            )
        ],
    ),
    "N16": (
        "the heading captured without the 250 ms brake",
        [
            (
                "envs/_flight.c",
                "*S(FC_TIME) < *S(LAST_YAW_INPUT) + HEADING_CAPTURE_DELAY_S",
                "*S(FC_TIME) < *S(LAST_YAW_INPUT)",
            )
        ],
    ),
    "N17": (
        "half the contact time counted",
        [
            (
                "envs/_flight.c",
                "if (touching) *S(CONTACT_S) += seconds;",
                "if (touching) *S(CONTACT_S) += 0.5 * seconds;",
            )
        ],
    ),
    "N18": (
        "AC_PID's integrator ignoring the limit flag",
        [("envs/_flight.c", "if (!limit || shrinking) {", "if (1) {")],
    ),
    "N19": (
        "the parameters packed once and never again",
        [
            (
                "envs/native_flight.py",
                "        if old is not None and all(a is b for a, b in zip(old, key, strict=True)):",
                "        if old is not None:",
            )
        ],
    ),
    "D1": (
        "dense depth without the baseline (z = f / d)",
        [("maptidal/perception/dense.py", "z = k.fx * k.baseline_m / d", "z = k.fx / d")],
    ),
    "D2": (
        "dense points turned by the camera's rotation transposed",
        [
            (
                "maptidal/perception/dense.py",
                "return position + camera @ rotation.T",
                "return position + camera @ rotation",
            )
        ],
    ),
    "D3": (
        "the far-range cut left out",
        [("maptidal/perception/dense.py", "(z <= params.max_depth_m)", "(z < np.inf)")],
    ),
    "D4": (
        "the map's dense points not carved to",
        [
            (
                "maptidal/map_discovery.py",
                "        self._carve(camera, points)\n        points = points[~near",
                "        points = points[~near",
            )
        ],
    ),
    "D5": (
        "the map's surface without its dense points",
        [
            (
                "maptidal/map_discovery.py",
                "np.concatenate([self.landmarks.rows(), self.surface.rows()])",
                "np.concatenate([self.landmarks.rows()])",
            )
        ],
    ),
    "D6": (
        "dense points on a teammate kept",
        [
            (
                "maptidal/map_discovery.py",
                "        points = points[~near_teammates(points, teammates, self.params)]\n",
                "",
            )
        ],
    ),
    "D7": (
        "the loop's keyframes without their dense depth",
        [("maptidal/mission/perception.py", "if robot_map.params.dense_depth:", "if False:")],
    ),
    "D8": (
        "the map's stacked points kept after dense points are added",
        [
            (
                "maptidal/map_discovery.py",
                "        self._stacked = None\n        for key, point in zip(keys",
                "        for key, point in zip(keys",
            )
        ],
    ),
    "D9": (
        "the map's stacked points kept after a keyframe's landmarks are added",
        [
            (
                "maptidal/map_discovery.py",
                "        self._stacked = None\n        for landmark, point, skip",
                "        for landmark, point, skip",
            )
        ],
    ),
    "D10": (
        "a known key given a new row in the map's point table",
        [
            (
                "maptidal/map_discovery.py",
                "row = self._row.setdefault(key, len(self._row))",
                "row = self._row[key] = len(self._row)",
            )
        ],
    ),
    "N20": (
        "the sensors left off in a period's last physics step too",
        [("envs/_flight.c", "  m->opt.disableflags = flags;\n  if (substeps > 0)", "  if (substeps > 0)")],
    ),
    "N21": (
        "every physics step of a period without its sensors (step_physics, Python)",
        [
            (
                "envs/simulation.py",
                "mujoco.mj_step(model, data, nstep=n_steps - 1)",
                "mujoco.mj_step(model, data, nstep=n_steps)",
            ),
            ("envs/simulation.py", "    if n_steps > 0:\n        mujoco.mj_step(model, data)\n", ""),
        ],
    ),
    "N22": (
        "the model's own disable flags dropped",
        [
            (
                "envs/_flight.c",
                "  m->opt.disableflags = flags | mjDSBL_SENSOR;",
                "  m->opt.disableflags = mjDSBL_SENSOR;",
            )
        ],
    ),
    "D11": (
        "views of any steepness kept",
        [
            (
                "maptidal/map_discovery.py",
                "flyable = np.abs(rows[:, 5]) <= math.sin(math.radians(params.max_view_pitch_deg)) + 1e-12",
                "flyable = np.ones(len(rows), bool)",
            )
        ],
    ),
    "D12": (
        "the dense points given no candidates",
        [
            (
                "maptidal/map_discovery.py",
                "    if surface_points is not None and cell_m > 0:",
                "    if False:",
            )
        ],
    ),
    "D13": (
        "the water surface seen from below kept in the map",
        [
            (
                "maptidal/map_discovery.py",
                "            points = points[~water_surface(points, self.params.surface_z, "
                "self.params.wall_reach_m)]\n        keys = _packed(",
                "            pass\n        keys = _packed(",
            )
        ],
    ),
    "D14": (
        "the loop's discovery without the keyframe's dense points",
        [("maptidal/mission/perception.py", "surface_points=surface,", "surface_points=None,")],
    ),
    "D15": (
        "the mission's maps without the steepest view its robots fly",
        [("maptidal/mission/run.py", ", max_view_pitch_deg=min(steepest, 90.0)", "")],
    ),
    "D16": (
        "no lift: a viewpoint out of free water is dropped, as before",
        [
            (
                "maptidal/map_discovery.py",
                "        waiting = np.flatnonzero(~free)\n",
                "        waiting = np.zeros(0, int)\n",
            )
        ],
    ),
    "D17": (
        "the lift only upwards",
        [("maptidal/map_discovery.py", "np.column_stack([sizes, -sizes]).ravel()", "sizes")],
    ),
    "D18": (
        "the largest lift tried first",
        [
            (
                "maptidal/map_discovery.py",
                "np.column_stack([sizes, -sizes]).ravel()",
                "np.column_stack([sizes, -sizes])[::-1].ravel()",
            )
        ],
    ),
    "D19": (
        "a lifted viewpoint re-aimed at its face's old height",
        [
            (
                "maptidal/map_discovery.py",
                "        moved[:, 2] += offset\n",
                "        moved[:, 2] += offset\n        moved[:, 5] -= offset\n",
            )
        ],
    ),
    "D20": (
        "the lift not bounded by the view's height",
        [
            (
                "maptidal/map_discovery.py",
                "    most = params.max_lift_fraction * discovery.standoff",
                "    most = 4.0 * params.max_lift_fraction * discovery.standoff",
            )
        ],
    ),
    "D21": (
        "no second try for a face whose ball is not planar",
        [
            (
                "maptidal/map_discovery.py",
                "    retry = np.flatnonzero(supported & ~planar)\n",
                "    retry = np.flatnonzero(np.zeros_like(supported))\n",
            )
        ],
    ),
    "D22": (
        "the refitted plane not asked to gather its points near it",
        [
            (
                "maptidal/map_discovery.py",
                "& (inner >= params.min_band_concentration)",
                "& (inner >= 0.0)",
            )
        ],
    ),
    "D23": (
        "the refitted plane not asked to span both ways",
        [
            (
                "maptidal/map_discovery.py",
                "(values[:, 1] >= tolerance**2)",
                "(values[:, 1] >= 0.0)",
            )
        ],
    ),
    "D24": (
        "a face off a planar ball's plane fitted again too",
        [
            (
                "maptidal/map_discovery.py",
                "    retry = np.flatnonzero(supported & ~planar)\n",
                "    retry = np.flatnonzero(supported & ~(planar & on_plane))\n",
            )
        ],
    ),
    "D25": (
        "the refit's plane kept from the face's own, not refitted",
        [
            (
                "maptidal/map_discovery.py",
                "        normal = np.linalg.eigh(covariance)[1][:, :, 0]\n",
                "",
            )
        ],
    ),
    "D26": (
        "faces beyond the region to inspect kept",
        [
            (
                "maptidal/map_discovery.py",
                '        inside = np.einsum("ij,ij->i", offsets, offsets) <= params.region_radius_m**2\n',
                "        inside = np.ones(len(offsets), bool)\n",
            )
        ],
    ),
    "D27": (
        "the robots' maps not told the region they explore",
        [
            (
                "maptidal/mission/run.py",
                "                        region_radius_m=params.frontier.explore_radius_m,\n",
                "",
            )
        ],
    ),
    "D28": (
        "any band point taken for a wall's, near a point beneath the band or not",
        [
            (
                "maptidal/map_discovery.py",
                "    surface[maybe_wall[np.isfinite(nearest)]] = False",
                "    surface[maybe_wall] = False",
            )
        ],
    ),
    "D29": (
        "points over the water surface's datum taken for a wall's top",
        [
            (
                "maptidal/map_discovery.py",
                "    maybe_wall = np.flatnonzero(band & (points[:, 2] < surface_z))",
                "    maybe_wall = np.flatnonzero(band)",
            )
        ],
    ),
    "D30": (
        "the map's dense depth not told the wall's reach (the whole band left out)",
        [
            (
                "maptidal/map_discovery.py",
                "points[~water_surface(points, self.params.surface_z, self.params.wall_reach_m)]",
                "points[~water_surface(points, self.params.surface_z, 0.0)]",
            )
        ],
    ),
    "D31": (
        "the band's support sought anywhere beneath it, not in the 15 cm just under it",
        [
            (
                "maptidal/map_discovery.py",
                "    beneath = points[~band & (points[:, 2] >= surface_z - 2.0 * SURFACE_BAND_M)]",
                "    beneath = points[~band]",
            )
        ],
    ),
    "D32": (
        "rule 5 without its exception for a face no view holds",
        [
            (
                "maptidal/map_discovery.py",
                "            needed = (fraction >= params.min_new_fraction) | ~face_seen\n",
                "            needed = fraction >= params.min_new_fraction\n",
            )
        ],
    ),
    "D33": (
        "rule 5's exception for every face, held or not",
        [
            (
                "maptidal/map_discovery.py",
                "            needed = (fraction >= params.min_new_fraction) | ~face_seen\n",
                "            needed = np.ones(len(rows), bool)\n",
            )
        ],
    ),
    "D34": (
        "the faces a chosen view holds not marked as held",
        [
            (
                "maptidal/map_discovery.py",
                "            face_seen |= face_in_view[best]\n",
                "",
            )
        ],
    ),
    "D35": (
        "the known tasks' views not asked whether they hold a candidate's face",
        [
            (
                "maptidal/map_discovery.py",
                "            face_seen = _covered(existing_rows, looked_at, camera)\n",
                "            pass\n",
            )
        ],
    ),
    "D42": (
        "no views of a map's gaps (session 33)",
        [
            (
                "maptidal/map_discovery.py",
                "    if cell_m <= 0 or len(robot_map.surface) == 0:\n",
                "    if True:\n",
            )
        ],
    ),
    "D43": (
        "the gaps judged without the known tasks' views",
        [
            (
                "maptidal/map_discovery.py",
                "        position,\n        existing,\n        discovery,\n        teammates=teammates,\n"
                "        surface_points=robot_map.surface.rows(),",
                "        position,\n        None,\n        discovery,\n        teammates=teammates,\n"
                "        surface_points=robot_map.surface.rows(),",
            )
        ],
    ),
    "D44": (
        "the gaps' candidates on the keyframes' dense-candidate grid (none by default)",
        [("maptidal/map_discovery.py", "        candidate_cell_m=cell_m,\n", "")],
    ),
    "D45": (
        "the gaps looked for while a teammate holds the robot's looks",
        [
            (
                "maptidal/mission/perception.py",
                "        if len(frontier) == 0 and held_for_teammates == 0:",
                "        if len(frontier) == 0:",
            )
        ],
    ),
    "D46": (
        "the gaps looked for while looks are left",
        [
            (
                "maptidal/mission/perception.py",
                "        if len(frontier) == 0 and held_for_teammates == 0:",
                "        if held_for_teammates == 0:",
            )
        ],
    ),
    "D47": (
        "the gaps' views not minted as tasks",
        [
            (
                "maptidal/mission/run.py",
                "            self._mint(robot, result.gap_tasks, now, result.time_s, gap=True)\n",
                "            pass\n",
            )
        ],
    ),
    "D48": (
        "a dense point given no plane to start its second try from",
        [
            (
                "maptidal/map_discovery.py",
                "    if point.any() and len(map_points) >= params.min_support:",
                "    if False:",
            )
        ],
    ),
    "D49": (
        "a dense point's second try started across its nearest points, not on their plane",
        [
            (
                "maptidal/map_discovery.py",
                'np.einsum("nki,nkj->nij", local, local))[1][:, :, 0]',
                'np.einsum("nki,nkj->nij", local, local))[1][:, :, 2]',
            )
        ],
    ),
    "D36": (
        "dense depth without its texture test",
        [
            (
                "maptidal/perception/dense.py",
                "matched &= textured_pixels(left_gray, block, threshold)",
                "matched &= True",
            )
        ],
    ),
    "D37": (
        "the grey image's noise without the channels' weights",
        [
            (
                "maptidal/perception/dense.py",
                "return math.sqrt((pixel_noise_sigma**2 + 1.0 / 12.0) * squares + 1.0 / 12.0)",
                "return math.sqrt(pixel_noise_sigma**2 + 1.0 / 12.0 + 1.0 / 12.0)",
            )
        ],
    ),
    "D38": (
        "the texture bound taken as a variance, not a standard deviation",
        [
            (
                "maptidal/perception/dense.py",
                "return noise_sigma * math.sqrt(chi2.ppf(confidence, dof) / dof)",
                "return noise_sigma * chi2.ppf(confidence, dof) / dof",
            )
        ],
    ),
    "D39": (
        "the block's spread compared with n, not n - 1, times the bound squared",
        [
            (
                "maptidal/perception/dense.py",
                "return spread > n * (n - 1) * threshold * threshold",
                "return spread > n * n * threshold * threshold",
            )
        ],
    ),
    "D40": (
        "the robots' dense depth not told the camera's noise",
        [
            (
                "maptidal/mission/run.py",
                "dense=DenseDepthParams(pixel_noise_sigma=camera_noise),",
                "dense=DenseDepthParams(),",
            )
        ],
    ),
    "D41": (
        "the camera's noise given with the water model off",
        [
            (
                "maptidal/mission/run.py",
                "camera_noise = water.noise_sigma if water.enabled else 0.0",
                "camera_noise = water.noise_sigma",
            )
        ],
    ),
    "P1": (
        "a baseline's viewpoints out of the reach band left out, not moved into it",
        [
            (
                "maptidal/mission/plan.py",
                "    rows[outside, 2] = np.clip(rows[outside, 2], low, high)\n",
                "",
            )
        ],
    ),
    "P2": (
        "a viewpoint below the band moved to its top edge",
        [
            (
                "maptidal/mission/plan.py",
                "np.clip(rows[outside, 2], low, high)",
                "np.where(rows[outside, 2] < low, high, low)",
            )
        ],
    ),
    "P3": (
        "viewpoints looking down moved as well",
        [
            (
                "maptidal/mission/plan.py",
                "    level = np.abs(rows[:, 5]) < 1e-6",
                "    level = np.abs(rows[:, 5]) < 2.0",
            )
        ],
    ),
    "P4": (
        "coinciding viewpoints merged whichever way they look",
        [("maptidal/mission/plan.py", " and rows[k, 3:] @ rows[j, 3:] > 0.999", "")],
    ),
    "P5": (
        "no merging of coinciding viewpoints",
        [("maptidal/mission/plan.py", "        if not duplicate:\n", "        if True:\n")],
    ),
    "W1": (
        "a teammate's way entered only through its end balls, never the cylinder's side",
        [
            (
                "maptidal/mission/clearance.py",
                "                entries.append(float(crossing))\n",
                "                pass\n",
            )
        ],
    ),
    "W2": (
        "a teammate's goal ignored: a ball where it was",
        [
            (
                "maptidal/mission/run.py",
                "        goal = agent.peer_goals.get(peer)\n",
                "        goal = None\n",
            )
        ],
    ),
    "W3": (
        "a teammate taken to have reached its goal whatever the message's age",
        [("maptidal/mission/run.py", "min(1.0, reach / distance) * to_goal", "to_goal")],
    ),
    "W4": (
        "the goal left out of the messages",
        [
            (
                "maptidal/allocation/messages.py",
                "    parts.append(_POSITION.pack(*_position_cm(message.goal)))\n",
                "    parts.append(_POSITION.pack(*_position_cm(None)))\n",
            )
        ],
    ),
    "W5": (
        "a new goal not news",
        [
            (
                "maptidal/allocation/agent.py",
                "            or _moved(self._sent_goal, self.goal, self.params.goal_news_m)\n",
                "",
            )
        ],
    ),
    "W6": (
        "a robot inside a teammate's way backs out of the way, not only of its ball",
        [
            (
                "maptidal/mission/clearance.py",
                "        offset = position - axis[0]\n",
                "        offset = position - nearest_on_axis(position, axis)\n",
            )
        ],
    ),
    "X1": (
        "faces outside the box to inspect yield candidates",
        [
            (
                "maptidal/map_discovery.py",
                "    if params.region_box is not None:\n        inside = in_box(",
                "    if False:\n        inside = in_box(",
            )
        ],
    ),
    "X2": (
        "rule 5 counts cells outside the box",
        [
            (
                "maptidal/map_discovery.py",
                "        cells = cells[in_box(cells, params.region_box, params.plane_tolerance_m)]\n",
                "        pass\n",
            )
        ],
    ),
    "X3": (
        "exploration ignores the box",
        [
            (
                "maptidal/exploration.py",
                "        outside |= ~_in_box(axes, params.explore_box)\n",
                "        pass\n",
            )
        ],
    ),
    "X4": (
        "the review counts no view as taken",
        [
            (
                "maptidal/map_discovery.py",
                "    covered = _covered(taken, cells, discovery.camera)\n",
                "    covered = np.zeros(len(cells), bool)\n",
            )
        ],
    ),
    "X5": (
        "the review counts the open tasks off the path as taken",
        [
            (
                "maptidal/mission/perception.py",
                "    done = None if job.existing_done is None else np.asarray(job.existing_done, bool)\n",
                "    done = None if job.existing_done is None else ~np.asarray(job.to_review, bool)\n",
            )
        ],
    ),
    "X6": (
        "a covered task flown all the same",
        [
            (
                "maptidal/mission/run.py",
                (
                    "            if key in robot.covered:\n                self._retire(robot, key, now)\n"
                    "                return\n            task = next("
                ),
                "            task = next(",
            )
        ],
    ),
    "X7": (
        "the box of the walls cut at half the water's depth",
        [
            (
                "maptidal/mission/plan.py",
                "    return np.asarray(tank.evaluated_surface().bounds, float)",
                "    return np.asarray(tank.evaluated_surface().bounds, float) * [[1, 1, 1], [1, 1, 0.5]]",
            )
        ],
    ),
    "X8": (
        "a repeat judged against views of higher key",
        [
            (
                "maptidal/map_discovery.py",
                "(known_keys[:, None] < row_keys[None, :]) & (finder",
                "(known_keys[:, None] != row_keys[None, :]) & (finder",
            )
        ],
    ),
    "X9": (
        "a robot's own views judged repeats of each other",
        [
            (
                "maptidal/map_discovery.py",
                " & (finder[:, None] != row_finder[None, :])\n",
                "\n",
            )
        ],
    ),
    "X10": (
        "a repeat needs no stand-in to hold its face",
        [
            (
                "maptidal/map_discovery.py",
                "    stands_for &= face_in_known\n",
                "    pass\n",
            )
        ],
    ),
    "X11": (
        "a repeat judged on rule 5's count alone, not its share",
        [
            (
                "maptidal/map_discovery.py",
                "(new < params.min_new_points) | (new < params.min_new_fraction * footprint)",
                "(new < params.min_new_points)",
            )
        ],
    ),
    "X12": (
        "the tasks a robot gave up stand in for repeats",
        [
            (
                "maptidal/mission/perception.py",
                "        stand_ins = np.asarray(job.stand_ins, bool)\n",
                "        stand_ins = np.ones(len(keys), bool)\n",
            )
        ],
    ),
    "X13": (
        "retire_repeats asked for, and no repeat review sent",
        [
            (
                "maptidal/mission/run.py",
                '"stand_ins": ~np.isin(keys, list(robot.skipped)) if self.params.retire_repeats else None,',
                '"stand_ins": None,',
            )
        ],
    ),
    "Y1": (
        "a look's gain counts unknown voxels outside the gain box too",
        [
            (
                "maptidal/exploration.py",
                "        seen_unknown &= grid.counted().ravel()[flat]\n",
                "        pass\n",
            )
        ],
    ),
    "Y2": (
        "the frontier borders unknown voxels outside the gain box too",
        [
            (
                "maptidal/exploration.py",
                "    padded = np.where(grid.counted(pad=1), np.pad(",
                "    padded = np.where(True, np.pad(",
            )
        ],
    ),
    "Y3": (
        "the gain box's cells placed without the padding",
        [
            (
                "maptidal/exploration.py",
                "(np.arange(n + 2 * pad) - pad + self.origin[d] + 0.5)",
                "(np.arange(n + 2 * pad) + self.origin[d] + 0.5)",
            )
        ],
    ),
    "Y4": (
        "the mission counts unknown water everywhere",
        [
            (
                "maptidal/mission/run.py",
                "params.frontier, explore_box=grown, gain_box=counted",
                "params.frontier, explore_box=grown",
            )
        ],
    ),
    "Y5": (
        "a survey flies to the look facing the way it came",
        [
            (
                "maptidal/mission/routes.py",
                "Route([PoseTrajectory(start, start_yaw, look, yaw, limits), *sweep])",
                "Route([PoseTrajectory(start, start_yaw, look, start_yaw, limits), *sweep])",
            )
        ],
    ),
    "Y6": (
        "a sweep does not turn back",
        [
            (
                "maptidal/mission/routes.py",
                "        PoseTrajectory(position, yaw - sweep_rad, position, yaw, limits),\n",
                "",
            )
        ],
    ),
    "Y7": (
        "a sweep turns to one side only",
        [
            (
                "maptidal/mission/routes.py",
                "        PoseTrajectory(position, yaw + sweep_rad, position, yaw - sweep_rad, limits),\n",
                "        PoseTrajectory(position, yaw + sweep_rad, position, yaw, limits),\n",
            )
        ],
    ),
    "U1": (
        "giving way counts before lost",
        [
            (
                "maptidal/mission/time_use.py",
                '    if lost:\n        return "lost"\n    if yielding:\n        return "giving way"\n',
                '    if yielding:\n        return "giving way"\n    if lost:\n        return "lost"\n',
            )
        ],
    ),
    "U2": (
        "a period counted to the occupation before it",
        [
            (
                "maptidal/mission/time_use.py",
                "        self.seconds[kind] = self.seconds.get(kind, 0.0) + elapsed_s",
                "        self.seconds[self._current or kind] = (\n"
                "            self.seconds.get(self._current or kind, 0.0) + elapsed_s\n"
                "        )",
            )
        ],
    ),
    "U3": (
        "the batch's lost seconds are the surveying ones",
        [
            (
                "maptidal/mission/outputs.py",
                'f"{kind}_s": round(sum(row["seconds"].get(kind, 0.0) for row in use.values()), 3)',
                'f"{kind}_s": round(sum(row["seconds"].get("surveying", 0.0) for row in use.values()), 3)',
            )
        ],
    ),
    "U4": (
        "a task counted for the survey under way when the frame's answer came, not when it was taken",
        [
            (
                "maptidal/mission/run.py",
                'if survey["start_s"] <= frame_s <= (',
                'if survey["start_s"] <= now <= (',
            )
        ],
    ),
    "U5": (
        "a survey's seconds counted as finding none whatever it found",
        [
            (
                "maptidal/mission/outputs.py",
                'zip(seconds, log, strict=True) if entry["tasks"] == 0',
                "zip(seconds, log, strict=True)",
            )
        ],
    ),
    "U6": (
        "a survey left standing down still counted",
        [("maptidal/mission/run.py", "            robot.survey_log.pop()\n", "")],
    ),
    "Y8": (
        "a robot without a DVL surveys with survey_without_dvl off",
        [
            (
                "maptidal/mission/run.py",
                "        if not robot.has_dvl and not self.params.survey_without_dvl:",
                "        if False:",
            )
        ],
    ),
    "Y9": (
        "a pitched look's rays turned nose up for nose down",
        [
            (
                "maptidal/exploration.py",
                "cos * rays[:, 0] + sin * rays[:, 2], rays[:, 1], cos * rays[:, 2] - sin * rays[:, 0]",
                "cos * rays[:, 0] - sin * rays[:, 2], rays[:, 1], cos * rays[:, 2] + sin * rays[:, 0]",
            )
        ],
    ),
    "Y10": (
        "every pitch's gains counted level",
        [
            (
                "maptidal/exploration.py",
                "look_gains(grid, candidates, yaws, params, pitch) for pitch in pitches",
                "look_gains(grid, candidates, yaws, params) for pitch in pitches",
            )
        ],
    ),
    "Y11": (
        "a pitched survey swept level",
        [
            (
                "maptidal/mission/run.py",
                'reference = dataclasses.replace(reference, pitch=robot.survey_log[-1]["pitch"] * share)',
                "reference = reference",
            )
        ],
    ),
    "Y12": (
        "a robot without a DVL takes pitched looks",
        [("maptidal/mission/run.py", " if robot.has_dvl else 0.0\n", "\n")],
    ),
    "Y13": (
        "each robot surveys with the other's sweep width",
        [
            (
                "maptidal/mission/run.py",
                "width = self.params.survey_sweep_deg if robot.has_dvl else",
                "width = self.params.survey_sweep_deg if not robot.has_dvl else",
            )
        ],
    ),
    "Y14": (
        "a robot with a DVL sweeps at the slow rate",
        [
            (
                "maptidal/mission/run.py",
                "        if not robot.has_dvl:\n            return self._limits()",
                "        return self._limits()",
            )
        ],
    ),
    "Y15": (
        "a survey's sweep at the flight's limits",
        [
            (
                "maptidal/mission/routes.py",
                "sweep_legs(look, yaw, sweep_rad, sweep_limits or limits)",
                "sweep_legs(look, yaw, sweep_rad, limits)",
            )
        ],
    ),
    "Y16": (
        "the first sweep at a survey's rate",
        [
            (
                "maptidal/mission/run.py",
                "robot.route = Route(self._sweep(here, yaw))",
                "robot.route = Route(sweep_legs(here, yaw, math.radians(self.params.explore_yaw_deg), "
                "self._sweep_limits(robot)))",
            )
        ],
    ),
    "Y17": (
        "a search with no look counts only the looks worth a trip for its best gain",
        [
            (
                "maptidal/exploration.py",
                "best_gain = float(gain.max()) if len(gain) else 0.0",
                "best_gain = float(rows[:, 5].max()) if len(rows) else 0.0",
            )
        ],
    ),
    "Y18": (
        "a robot that has explored does not say why",
        [("maptidal/mission/run.py", "why = dict(robot.frontier_summary or {})", "why = {}")],
    ),
    "Y19": (
        "the report's rebuild forgets why a robot stopped exploring",
        [
            (
                "maptidal/mission/outputs.py",
                '    if explored:\n        document["explored"]',
                '    if False:\n        document["explored"]',
            )
        ],
    ),
    "Y20": (
        "a batch counts each robot's reasons once for the whole batch, not per mission",
        [
            (
                "maptidal/mission/batch.py",
                "counts[reason] = counts.get(reason, 0) + 1",
                "counts[reason] = 1",
            )
        ],
    ),
    "Z1": (
        "a robot standing down keeps its bundle",
        [("maptidal/allocation/agent.py", "        self._drop_from_bundle(set(self.bundle))\n", "")],
    ),
    "Z2": (
        "a robot standing down bids all the same",
        [
            (
                "maptidal/allocation/agent.py",
                "        if not self.alive or self.standing_down or not self.n_tasks:\n"
                "            return False\n        limit",
                "        if not self.alive or not self.n_tasks:\n            return False\n        limit",
            )
        ],
    ),
    "Z3": (
        "a robot still lost after its recovery does not stand down",
        [
            (
                "maptidal/mission/run.py",
                "                self._stand_down(robot, now)  # home,",
                "                pass  # home,",
            )
        ],
    ),
    "Z4": (
        "a robot standing down takes its next task or look",
        [
            (
                "maptidal/mission/run.py",
                "            if agent.standing_down:\n                return",
                "            if False:\n                return",
            )
        ],
    ),
    "Z5": (
        "the mission waits on a robot standing down",
        [
            (
                "maptidal/mission/run.py",
                "if r.active and not self._standing_down(r)]",
                "if r.active]",
            )
        ],
    ),
    "Z7": (
        "a robot standing down flies home again",
        [
            (
                "maptidal/mission/run.py",
                "        if self._standing_down(robot):\n            robot.recovery",
                "        if False:\n            robot.recovery",
            )
        ],
    ),
    "Z6": (
        "a robot found again does not bid again",
        [
            (
                "maptidal/mission/run.py",
                "                if self.auction.agents[robot.index].resume(now):",
                "                if False:",
            )
        ],
    ),
    "C1": (
        "the difference the other way round",
        [("maptidal/mission/batch_compare.py", "    differences = a - b\n", "    differences = b - a\n")],
    ),
    "C2": (
        "the population deviation in the interval",
        [("maptidal/mission/batch_compare.py", "differences.std(ddof=1)", "differences.std()")],
    ),
    "C3": (
        "a one-sided t quantile",
        [
            (
                "maptidal/mission/batch_compare.py",
                "stats.t.ppf(0.5 + CONFIDENCE / 2, len",
                "stats.t.ppf(CONFIDENCE, len",
            )
        ],
    ),
    "C4": (
        "seeds paired that one batch lacks",
        [
            (
                "maptidal/mission/batch_compare.py",
                "seeds = tuple(sorted(set(before) & set(after)))",
                "seeds = tuple(sorted(set(before) | set(after)))",
            )
        ],
    ),
    "C5": (
        "a tie counted as lower",
        [("maptidal/mission/batch_compare.py", "return sum(a < b for a, b", "return sum(a <= b for a, b")],
    ),
    "K1": (
        "the estimator's thrust lag a fixed half step",
        [("controllers/estimation.py", "(1.0 - math.exp(-dt / lag))", "(0.5)")],
    ),
    "K2": (
        "the compiled estimator's thrust lag a fixed half step",
        [("envs/_flight.c", "(1.0 - exp(-dt / lag))", "(0.5)")],
    ),
    "K3": (
        "the batched estimator's thrust lag a fixed half step",
        [("controllers/batched.py", "(1.0 - math.exp(-dt / self._thrust_lag_s))", "(0.5)")],
    ),
    "K4": (
        "gravity left in the compiled period mean",
        [("envs/_flight.c", "/ period_s - m->opt.gravity[k];", "/ period_s;")],
    ),
    "K5": (
        "the period mean in world axes, not body axes",
        [
            (
                "envs/simulation.py",
                "[x[j] * w[0] + x[3 + j] * w[1] + x[6 + j] * w[2] for j in range(3)]",
                "[w[0], w[1], w[2]]",
            )
        ],
    ),
    "A1": (
        "the world's vertical in body axes with the roll's sign flipped",
        [
            (
                "maptidal/perception/unmodelled.py",
                "math.sin(roll) * math.cos(pitch), math",
                "-math.sin(roll) * math.cos(pitch), math",
            )
        ],
    ),
    "A2": (
        "the turn's w x v left out of the model's sway acceleration",
        [
            (
                "maptidal/perception/unmodelled.py",
                "(vy - previous[1]) / dt + wz * vx - wx * vz,",
                "(vy - previous[1]) / dt,",
            )
        ],
    ),
    "A3": (
        "no glide after a push",
        [
            (
                "maptidal/perception/unmodelled.py",
                "self.coasting, self.elapsed_s = p.inertia is not None and settled, 0.0",
                "self.coasting, self.elapsed_s = False, 0.0",
            )
        ],
    ),
    "A4": (
        "the front end's uncertainty not grown by the unmodelled distance",
        [("maptidal/perception/odometry.py", "self.sigma_m += unmodelled_m", "self.sigma_m += 0.0")],
    ),
    "A5": (
        "the mission hands the front end no unmodelled distance",
        [("maptidal/mission/run.py", "unmodelled_m=robot.unmodelled.take(),", "unmodelled_m=0.0,")],
    ),
    "A6": (
        "a DVL's periods taken as the model's",
        [("maptidal/mission/run.py", 'modelled = dvl is None or not dvl["valid"]', "modelled = True")],
    ),
    "A7": (
        "the accelerometer's offset never learned",
        [("maptidal/perception/unmodelled.py", "learn = min(dt / p.offset_s, 1.0)", "learn = 0.0")],
    ),
    "A8": (
        "a push's start forgets the velocity it gave while the filter rose",
        [
            (
                "maptidal/perception/unmodelled.py",
                "self.velocity[i] + recent[i] - dt * difference[i]",
                "self.velocity[i]",
            )
        ],
    ),
    "A9": (
        "the watch on the estimator's vertical (no gyro-held vertical of its own)",
        [
            (
                "maptidal/perception/unmodelled.py",
                "up = self._vertical(gyro_body, up_in_body(roll, pitch), dt)",
                "up = up_in_body(roll, pitch)",
            )
        ],
    ),
    "A10": (
        "the gyro's bias never learned",
        [
            (
                "maptidal/perception/unmodelled.py",
                "integral = 0.25 * proportional * proportional",
                "integral = 0.0",
            )
        ],
    ),
    "A11": (
        "the glide's slowing taken for a new push",
        [
            (
                "maptidal/perception/unmodelled.py",
                "difference = [difference[i] - glide[i] for i in range(3)]",
                "difference = difference",
            )
        ],
    ),
    "H1": (
        "a teammate without a DVL taken for one that can take the view",
        [
            (
                "maptidal/mission/run.py",
                "if not (idle and heard is not None and self.robots_by_index[peer].has_dvl):",
                "if not (idle and heard is not None):",
            )
        ],
    ),
    "H2": (
        "a teammate heard idle long ago taken as idle now",
        [("maptidal/mission/run.py", "if now - heard_s <= self.params.peer_fresh_s and lost_s", "if lost_s")],
    ),
    "H3": (
        "the view handed over at the first loss, whatever the hand-over costs",
        [("maptidal/mission/run.py", " and lost_s >= cycle_s + flight_s:", ":")],
    ),
    "H4": (
        "a busy teammate taken for an idle one",
        [("maptidal/mission/run.py", "if not (idle and heard is not None", "if not (heard is not None")],
    ),
    "H5": (
        "the teammate's flight left out of the hand-over's cost",
        [("maptidal/mission/run.py", "lost_s >= cycle_s + flight_s", "lost_s >= cycle_s")],
    ),
    "H6": (
        "the time flown found counted as lost on the way",
        [("maptidal/mission/time_use.py", "            if held == kind\n", "")],
    ),
    "H7": (
        "the time lost carried over to the next view",
        [
            (
                "maptidal/mission/run.py",
                'seconds_since("lost", robot.task_started_s, now)',
                'seconds_since("lost", 0.0, now)',
            )
        ],
    ),
    "H8": (
        "a robot found again hands its view over",
        [
            (
                "maptidal/mission/run.py",
                "elif robot.lost and (taker := self._taker(",
                "elif (taker := self._taker(",
            )
        ],
    ),
    "H9": (
        "the hand-over on by default",
        [
            (
                "maptidal/mission/params.py",
                "    lost_hand_over: bool = False\n",
                "    lost_hand_over: bool = True\n",
            )
        ],
    ),
    "G1": (
        "the search's ratio test lets an equal second nearest pass",
        [
            (
                "maptidal/perception/relocalisation.py",
                "(first64 >= params.ratio * second64)",
                "(first64 > params.ratio * second64)",
            )
        ],
    ),
    "G2": (
        "an anchor taken by two keypoints at one distance keeps the later",
        [
            (
                "maptidal/perception/relocalisation.py",
                "np.lexsort((keypoints, score, anchors))",
                "np.lexsort((-keypoints, score, anchors))",
            )
        ],
    ),
    "G3": (
        "the second nearest taken as the nearest",
        [("maptidal/perception/relocalisation.py", "    rest[nearest] = np.inf\n", "")],
    ),
    "G4": (
        "every keypoint's distances worked out from the first keypoint's descriptor",
        [
            (
                "maptidal/perception/relocalisation.py",
                "distances[row] = descriptor_distances(self.descriptors, descriptors[row][None])",
                "distances[row] = descriptor_distances(self.descriptors, descriptors[0][None])",
            )
        ],
    ),
    "G5": (
        "RANSAC keeps the last hypothesis of the most inliers",
        [
            (
                "maptidal/perception/relocalisation.py",
                "best = inliers[int(np.argmax(inliers.sum(axis=1)))]",
                "best = inliers[len(inliers) - 1 - int(np.argmax(inliers.sum(axis=1)[::-1]))]",
            )
        ],
    ),
    "G6": (
        "RANSAC takes the first hypothesis",
        [
            (
                "maptidal/perception/relocalisation.py",
                "best = inliers[int(np.argmax(inliers.sum(axis=1)))]",
                "best = inliers[0]",
            )
        ],
    ),
    "G7": (
        "two parallel rays taken to fix a centre",
        [
            (
                "maptidal/perception/relocalisation.py",
                "fixed = np.flatnonzero(~(np.linalg.cond(normals) > 1e8))",
                "fixed = np.arange(len(normals))",
            )
        ],
    ),
    "G8": (
        "a point behind the camera counted as an inlier",
        [
            (
                "maptidal/perception/relocalisation.py",
                "axis=2)\n    return (depth > 0) & (error <= threshold_px)\n",
                "axis=2)\n    return error <= threshold_px\n",
            )
        ],
    ),
    "G9": (
        "each hypothesis's second point taken for its first",
        [
            (
                "maptidal/perception/relocalisation.py",
                'right = np.einsum("bnij,bnj->bi", projectors[fixed], points[pairs[fixed]])',
                'right = np.einsum("bnij,bnj->bi", projectors[fixed], points[pairs[fixed]][:, ::-1])',
            )
        ],
    ),
}


def run(ids: list[str]) -> int:
    survived = []
    for key in ids:
        description, edits = MUTATIONS[key]
        originals = {}
        try:
            for name, old, new in edits:
                path = ROOT / name
                text = originals.setdefault(path, path.read_text())
                current = path.read_text()
                if old not in current:
                    raise SystemExit(f"{key}: the text to mutate is not in {name}; update the mutation list")
                path.write_text(current.replace(old, new, 1))
            result = subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "pytest",
                    "-x",
                    "-q",
                    "-p",
                    "no:cacheprovider",
                    *TESTS_OF_GROUP[key[0]],
                ],
                cwd=ROOT,
                capture_output=True,
                text=True,
            )
            failed = [
                line.split(" ", 1)[1]
                for line in result.stdout.splitlines()
                if line.startswith(("FAILED ", "ERROR "))
            ] or ["an error before any test ran"]
            verdict = f"killed by {failed[0].split(' - ')[0]}" if result.returncode else "SURVIVED"
            if not result.returncode:
                survived.append(key)
            print(f"{key}  {description}: {verdict}", flush=True)
        finally:
            for path, text in originals.items():
                path.write_text(text)
    print("all killed" if not survived else f"survived: {', '.join(survived)}")
    return 1 if survived else 0


if __name__ == "__main__":
    sys.exit(run(sys.argv[1:] or list(MUTATIONS)))
