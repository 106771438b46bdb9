"""The bench's baseline protocol (bench/baselines.py, bench/odometry.py): the open3d grid is the one documented,
settings are labelled unambiguously, the score puts diverged runs last, and a missing optional package leaves its
method out with a note instead of a traceback. No timing is asserted."""

import sys

import pytest

from bench import baselines, odometry


def test_the_grid_covers_scan_to_scan_and_scan_to_map_windows_voxels_and_distances():
    grid = baselines.icp_grid()
    assert len(grid) == 2 * 4 * 3 * 3 == len({tuple(sorted(g.items())) for g in grid})
    assert {g["map_scans"] for g in grid} == {1, 5, 10, 20}
    assert {g["voxel"] for g in grid} == {None, 0.3, 0.5}
    assert {g["max_correspondence"] for g in grid} == {0.5, 1.0, 2.0}
    assert {g["method"] for g in grid} == {"point_to_point", "point_to_plane"}
    assert not any(g["doppler_filter"] for g in grid) and all(g["doppler_init"] for g in grid)
    assert {**baselines.ICP_TUNED, "doppler_filter": False} in grid  # the stored winner is a grid setting


def test_labels_name_every_setting():
    labels = {baselines.describe_icp(g) for g in baselines.icp_grid()}
    assert len(labels) == len(baselines.icp_grid())
    assert baselines.describe_icp({"method": "point_to_plane", "map_scans": 1, "voxel": None,
                                   "max_correspondence": 2.0, "doppler_filter": True}) == \
        "point-to-plane, scan-to-scan, no voxel, max corr. 2 m, Doppler-filtered"


def test_score_orders_by_t_err_then_r_err_then_time_and_puts_nan_last():
    rows = [{"t_err": float("nan"), "r_err": 0.0, "median_ms": 1.0},
            {"t_err": 1.0, "r_err": 0.02, "median_ms": 1.0},
            {"t_err": 1.0, "r_err": 0.01, "median_ms": 9.0},
            {"t_err": 2.0, "r_err": 0.0, "median_ms": 0.1}]
    ordered = sorted(rows, key=baselines._score)
    assert ordered == [rows[2], rows[1], rows[3], rows[0]]


@pytest.mark.parametrize("missing", ["open3d", "kiss_icp"])
def test_a_missing_package_is_a_note_and_its_method_is_left_out(monkeypatch, missing):
    monkeypatch.setitem(sys.modules, missing, None)  # import raises ImportError
    notes = baselines.available()
    assert "not installed" in notes[missing] and "rodo[icp]" in notes[missing]
    icp_kw, kiss_vx, lines, alternatives = odometry._tune(True, notes)
    assert alternatives == []  # the quick bench checks no alternatives
    labels = [label for label, _, _ in odometry._methods(icp_kw, kiss_vx)]
    assert labels[:2] == ["CV/C", "CA/P"]
    assert ("open3d ICP" in labels) == (missing != "open3d")
    assert ("KISS-ICP" in labels) == (missing != "kiss_icp")


def test_alternatives_are_the_winner_with_doppler_and_the_best_of_other_families():
    grid = baselines.icp_grid()
    rows = [{"setting": s} for s in grid]  # in grid order: point-to-point, scan-to-scan first
    alt = baselines.icp_alternatives(rows)
    assert alt[0] == grid[0] and alt[1] == {**grid[0], "doppler_filter": True}
    assert alt[2]["method"] == "point_to_plane" and len(alt) == 3  # grid[0] is already the best scan-to-scan


def test_the_alternating_table_has_one_row_per_sequence_with_the_ratio_of_its_medians():
    """`odometry._alternating`: CA/P and CV/C in turn on a short sequence; with one repeat the ratio is the two
    medians' ratio (to the table's rounding) and its range is that one value."""
    lines = odometry._alternating(["city"], 1, duration=2.0)
    rows = [line for line in lines if line.startswith("| city")]
    assert len(rows) == 1
    cells = [c.strip() for c in rows[0].strip("|").split("|")]
    assert cells[:2] == ["city 2 s", "1"]
    cv, ca, ratio = float(cells[2]), float(cells[3]), float(cells[4].rstrip("x"))
    assert ratio == pytest.approx(ca / cv, abs=0.01 + 0.06 * ca / cv)  # the ms are rounded to 0.1
    assert cells[5] == f"{ratio:.2f}-{ratio:.2f}x"
