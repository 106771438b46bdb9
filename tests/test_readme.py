"""The README's Python example runs as written (an example that does not run is a defect)."""

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


@pytest.mark.slow
def test_readme_python_example_runs(capsys):
    """The example runs as written, and what it computes is right: the odometry follows the simulated truth
    (final position error under 2 % of the distance driven) and the absolute pose covariance it prints is
    positive definite and has grown past the first scan's."""
    import numpy as np

    from rodo.estimator.lie import se3

    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), re.S)
    assert blocks, "README.md has no ```python block"
    namespace: dict = {}
    for code in blocks:
        exec(compile(code, str(README), "exec"), namespace)
    assert capsys.readouterr().out.strip(), "the example printed nothing"
    result, truth = namespace["result"], namespace["truth"]
    T_true = truth["T_vehicle_world"][-1] @ se3.inverse(truth["T_vehicle_world"][0])
    T_est = result.estimates[-1].T_vehicle_world @ se3.inverse(result.estimates[0].T_vehicle_world)
    p_true, p_est = se3.inverse(T_true)[:3, 3], se3.inverse(T_est)[:3, 3]
    path = np.sum(np.linalg.norm(np.diff(se3.inverse(truth["T_vehicle_world"])[:, :3, 3], axis=0), axis=1))
    assert path > 10 and np.linalg.norm(p_est - p_true) < 0.02 * path
    P = result.estimates[-1].P_pose_absolute
    assert np.all(np.linalg.eigvalsh(P) > 0) and np.trace(P) > np.trace(result.estimates[1].P_pose_absolute)
