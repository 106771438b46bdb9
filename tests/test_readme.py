"""The Python examples of README.md and docs/estimator.md run as written (an example that does not run is a
defect), and what they compute is right."""

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
ESTIMATOR_DOC = README.parent / "docs" / "estimator.md"


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


@pytest.mark.slow
def test_the_scan_by_scan_example_of_the_estimator_doc_runs(capsys):
    """docs/estimator.md, "Scan by scan from Python": the loop gives what `run_sequence` gives (the same estimator,
    scan by scan) and follows the simulated truth."""
    import numpy as np

    from rodo.estimator.lie import se3
    from rodo.validation.driver import run_sequence

    blocks = re.findall(r"```python\n(.*?)```", ESTIMATOR_DOC.read_text(), re.S)
    assert len(blocks) == 1, "docs/estimator.md should have one ```python block"
    namespace: dict = {}
    exec(compile(blocks[0], str(ESTIMATOR_DOC), "exec"), namespace)
    assert capsys.readouterr().out.strip(), "the example printed nothing"
    seq, truth, estimate = namespace["seq"], namespace["truth"], namespace["estimate"]
    result = run_sequence(seq, namespace["OdometryConfig"].for_model("ca-polar"))
    np.testing.assert_allclose(estimate.T_vehicle_world, result.estimates[-1].T_vehicle_world, atol=1e-9)
    T_true = truth["T_vehicle_world"][-1] @ se3.inverse(truth["T_vehicle_world"][0])
    p_true = se3.inverse(T_true)[:3, 3]
    p_est = se3.inverse(estimate.T_vehicle_world @ se3.inverse(result.estimates[0].T_vehicle_world))[:3, 3]
    assert np.linalg.norm(p_true) > 10 and np.linalg.norm(p_est - p_true) < 0.02 * np.linalg.norm(p_true)
