"""The mission report's localisation figures (maptidal.mission.outputs.localisation_errors), against
errors worked out by hand from a trajectories.csv written here."""

from __future__ import annotations

import math

import numpy as np
import pytest

from maptidal.mission.outputs import localisation_errors, localisation_lines


def test_localisation_errors_are_the_horizontal_errors_of_the_estimate(tmp_path):
    lines = ["time_s,robot,true_x,true_y,true_z,est_x,est_y,est_z,true_yaw"]
    errors_a = [0.0, 0.03, 0.04, 0.12]  # rov0: along x; depth errors must not count
    for t, e in enumerate(errors_a):
        lines.append(f"{t},rov0,1.0,2.0,1.0,{1.0 + e},2.0,1.5,0.0")
    lines.append("0,rov1,0.0,0.0,1.0,0.3,0.4,1.0,0.0")  # 0.5 m off in the plane
    lines.append("1,rov1,0.0,0.0,1.0,0.0")  # a line cut by a kill: skipped
    (tmp_path / "trajectories.csv").write_text("\n".join(lines) + "\n")
    out = localisation_errors(tmp_path, ["rov0", "rov1", "rov2"])
    assert set(out) == {"rov0", "rov1"}  # rov2 has no row
    a = out["rov0"]
    assert a["ate_m"] == pytest.approx(math.sqrt(np.mean(np.square(errors_a))))
    assert a["median_m"] == pytest.approx(0.035)
    assert a["max_m"] == pytest.approx(0.12) and a["final_m"] == pytest.approx(0.12)
    assert a["p90_m"] == pytest.approx(np.percentile(errors_a, 90))
    assert out["rov1"]["median_m"] == pytest.approx(0.5)
    table = "\n".join(localisation_lines({"localisation": out}))
    assert "| rov1 | 50.0 cm | 50.0 cm |" in table and "localisation.png" in table
    assert localisation_lines({}) == []
