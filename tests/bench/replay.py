"""Recording a simulation's controls period by period, for a bare ``mj_step`` side to replay: the benches'
way to give bare MuJoCo the very physics an environment flies."""

from __future__ import annotations

import mujoco
import numpy as np


def record_periods(sim) -> list[tuple[np.ndarray, np.ndarray]]:
    """Make ``sim`` fly one control period at a time (the compiled flight stack flies a period alike
    alone and among others, bit for bit) and record, after each, its controls and its userdata (which
    holds the water current); the record, filled as ``sim`` flies."""
    whole = sim.step_periods
    record: list[tuple[np.ndarray, np.ndarray]] = []

    def one_period_at_a_time(commands, n_periods=1, mode="pilot", currents=None):
        parts = []
        for period in range(n_periods):
            current = None if currents is None else currents[period : period + 1]
            parts.append(whole(commands, 1, mode, current))
            record.append((sim.data.ctrl.copy(), sim.data.userdata.copy()))
        return np.concatenate(parts)

    sim.step_periods = one_period_at_a_time
    return record


def plain_mj_step(model, data, n_steps: int) -> None:
    """``n_steps`` of bare ``mj_step``, the sensors computed in every one: the benches' plain bare side,
    beside ``maptidal.envs.simulation.step_physics`` (the sensors only where they are read)."""
    mujoco.mj_step(model, data, nstep=n_steps)
