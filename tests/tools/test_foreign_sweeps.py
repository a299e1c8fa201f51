"""idm-gap diagnose on sweeps it did not write: datasets from foreign_sweep.py (another lab's
writer and simulator, Python's standard library only, checked against the paper's reference
vectors), in the layouts docs/sweep-dataset.md allows. The same physics written two ways reads
the same; the reading noise is found without rows at rest and far from the interferometer's zero;
an amplifier the writer integrates is named with its cutoff; cells with too few trials are left
out and listed."""
import json
import math
import os
import re
import subprocess

import pytest

import foreign_sweep

IDM_GAP = os.environ.get("IDM_GAP", "")
# The paper's reference vectors, in the tree (tests/data/README.md).
VECTORS = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "data",
                       "impulse-model-vectors.csv")


def diagnose(dataset, tmp_path):
    """(summary text, report JSON) of `idm-gap diagnose DATASET --json`."""
    out = os.path.join(str(tmp_path), os.path.basename(dataset) + ".json")
    r = subprocess.run([IDM_GAP, "diagnose", dataset, "--threads", "1", "--json", out],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, (r.returncode, r.stdout, r.stderr)
    with open(out) as fh:
        return r.stdout, json.load(fh)


def reading_noise_m(summary):
    m = re.search(r"reading noise ([0-9.e+-]+) m", summary)
    assert m, summary
    return float(m.group(1))


def expected_noise_m(noise_m, resolution_m):
    """The Gaussian noise and the quantization of one count, together."""
    return math.sqrt(noise_m ** 2 + resolution_m ** 2 / 12)


def test_the_writer_reproduces_the_papers_reference_vectors():
    worst, integrated = foreign_sweep.selftest(VECTORS)
    assert worst < 1e-12
    assert integrated < 4e-9  # the integrator with a 1 GHz amplifier against the exact model


def test_another_layout_of_the_same_sweep_reads_the_same(tmp_path):
    plain = str(tmp_path / "plain")
    foreign = str(tmp_path / "foreign")
    foreign_sweep.write_sweep(plain, seed=11, trials=4)
    foreign_sweep.write_sweep(foreign, seed=11, trials=4, foreign_layout=True, quoted_notes=True,
                              minimal_yaml=True, crlf=True, no_final_newline=True, bom=True,
                              sci_upper=True, cycles_float=True)
    summary_a, a = diagnose(plain, tmp_path)
    summary_b, b = diagnose(foreign, tmp_path)
    for summary, report in ((summary_a, a), (summary_b, b)):
        assert report["diagnosis"]["effects"] == [], summary
        assert report["dataset_status"]["cells_used"] == 25
        assert report["baseline"]["gap"] < 1.5, summary  # an ideal stage: within the noise
        assert abs(report["diagnosis"]["friction_coefficient"] - 0.4) < 0.002
        assert reading_noise_m(summary) == pytest.approx(expected_noise_m(2e-9, 5e-9), rel=0.25)
    # The same trials (held out in another order: the rows are shuffled) read alike.
    assert b["baseline"]["gap"] == pytest.approx(a["baseline"]["gap"], rel=0.15)
    assert b["diagnosis"]["friction_coefficient"] == pytest.approx(
        a["diagnosis"]["friction_coefficient"], abs=5e-4)
    assert reading_noise_m(summary_b) == pytest.approx(reading_noise_m(summary_a), rel=0.05)


def test_the_noise_without_rest_far_from_zero_on_an_offset_grid_at_mixed_rates(tmp_path):
    dataset = str(tmp_path / "norest")
    foreign_sweep.write_sweep(dataset, seed=16, trials=4, noise_m=3e-9, no_rest=True,
                              grid_offset=-0.3, rates_hz=(12345.6, 33333.3),
                              x_offset_m=1.2345678)
    summary, report = diagnose(dataset, tmp_path)
    assert reading_noise_m(summary) == pytest.approx(expected_noise_m(3e-9, 5e-9), rel=0.3)
    assert report["diagnosis"]["effects"] == [], summary
    assert not report["diagnosis"]["unexplained"]["significant"], summary


def test_an_amplifier_is_named_with_its_cutoff(tmp_path):
    dataset = str(tmp_path / "amp1500")
    foreign_sweep.write_sweep(dataset, seed=12, trials=4, amp_fc_hz=1500, x_offset_m=0.3)
    summary, report = diagnose(dataset, tmp_path)
    d = report["diagnosis"]
    assert d["effects"] == ["amplifier"], summary
    assert d["params"]["amplifier"]["order"] == 1
    low, high = d["intervals"]["amplifier"]["cutoff_hz"]
    assert low < 1500 < high and high - low < 0.3 * 1500, (low, high)
    assert abs(d["friction_coefficient"] - 0.4) < 0.01
    assert d["gap_before"] > 3 and d["shrink"] > 0.75, summary
    assert not d["unexplained"]["significant"]
    # what the diagnosis cannot know from one stroke in one direction, it says
    assert {n["effect"] for n in d["not_identifiable"]} == {"hysteresis", "tilt"}


def test_cells_with_too_few_trials_are_left_out_and_listed(tmp_path):
    dataset = str(tmp_path / "unbalanced")
    cells = foreign_sweep.write_sweep(dataset, seed=28, trials=5, trials_min=2)
    short = sorted(k for k, n in cells.items() if n < 3)
    assert short, "the draw has no cell of 2 trials"
    summary, report = diagnose(dataset, tmp_path)
    status = report["dataset_status"]
    assert status["status"] == "unmarked"
    assert sorted(tuple(c) for c in status["cells_left_out"]) == \
        sorted((f, d, s) for f, d, s in short)
    assert status["cells_used"] == len(cells) - len(short)
    assert "(2 trials)" in summary, summary
    assert report["diagnosis"]["effects"] == [], summary
