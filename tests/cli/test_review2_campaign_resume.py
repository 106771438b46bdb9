"""A refused resume of a campaign (validation/campaign_dir.py) says what differs in one short line: an edited
LABEL=CONFIG.toml is named by its label and SHA-256 prefixes, not by the two config texts (53 kB of stderr)."""

import hashlib

from rodo.cli import main
from rodo.validation.campaign_dir import describe_difference
from tests.cli.helpers import fails


def _sha(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:12]


def test_resume_with_an_edited_config_names_the_label_briefly(tmp_path, capsys):
    assert main(["config", "dump", "--model", "cv-cartesian"]) == 0
    cv = tmp_path / "cv.toml"
    cv.write_text(capsys.readouterr().out)
    before = cv.read_text()
    out = tmp_path / "mc"
    argv = ["montecarlo", "city", "--runs", "1", "--duration", "0.5", "--jobs", "1", "--models",
            f"cv-cartesian,cvx={cv}", "--out", out]
    assert main([str(a) for a in argv]) == 0
    capsys.readouterr()
    rows = (out / "results.csv").read_text()
    cv.write_text(before + "# edit\n")
    err = fails(capsys, argv[:3] + ["2"] + argv[4:] + ["--resume"], "campaign.json", "different campaign",
                f"configs: cvx changed (saved sha256 {_sha(before)}", f"now sha256 {_sha(before + '# edit' + chr(10))}")
    assert len(before) > 5000 and len(err) < 500, len(err)
    assert "model =" not in err  # no config text
    assert (out / "results.csv").read_text() == rows  # nothing ran


def test_describe_difference_keeps_short_values_and_digests_long_ones():
    long_a, long_b = "a" * 3000, "b" * 3000
    assert describe_difference("seed", 0, 1) == "seed: saved 0, now 1"
    assert describe_difference("models", ["ca-polar"], ["ca-polar", "cvx"]) == \
        "models: saved ['ca-polar'], now ['ca-polar', 'cvx']"
    text = describe_difference("configs", {"x": long_a, "y": long_a, "z": long_a},
                               {"x": long_a, "y": long_b, "w": long_b})
    assert text == (f"configs: w added (sha256 {_sha(long_b)}, 3000 characters), "
                    f"y changed (saved sha256 {_sha(long_a)}, 3000 characters; now sha256 {_sha(long_b)}, 3000 "
                    f"characters), z removed (saved sha256 {_sha(long_a)}, 3000 characters)")
    assert describe_difference("configs", None, {"cvx": long_a}) == \
        f"configs: saved None, now {{'cvx': sha256 {_sha(long_a)}, 3000 characters}}"
    qc = describe_difference("qc", list(range(100)), list(range(101)))
    assert qc.startswith("qc: saved list of JSON sha256 ") and len(qc) < 150
