"""idm-gap diagnose on datasets whose values are drawn across and beyond what a stage and a sweep
can be (frequencies, duties, strokes, cycles, sample rates, trials, masses, stiffnesses, numbers
that are not finite), from a fixed seed: each is diagnosed (exit 0) or refused with one line that
names a file of the dataset (exit 2); never a crash, never bad_alloc, never a run past its bound
(each run is a subprocess with a time limit and an address-space limit)."""
import math
import os
import random
import resource
import subprocess

import pytest

IDM_GAP = os.environ.get("IDM_GAP", "")
SEED = 20240601
RUNS = 40
TIME_LIMIT_S = 240
ADDRESS_SPACE_BYTES = 4 << 30


BAD = (0.0, -1.0, 1e-300, 1e300, float("nan"), float("inf"))


def pick(rng, lo_exp, hi_exp, beyond=2.0):
    """Log-uniform across the legal 10^lo_exp..10^hi_exp nine times in ten; else up to `beyond`
    decades past either end, or a special number (0, negative, tiny, huge, not finite)."""
    u = rng.random()
    if u < 0.9:
        return 10 ** rng.uniform(lo_exp, hi_exp)
    if u < 0.95:
        return 10 ** rng.choice([rng.uniform(lo_exp - beyond, lo_exp), rng.uniform(hi_exp, hi_exp + beyond)])
    return rng.choice(BAD)


def draw(rng):
    """One dataset's values, each drawn across its legal range (recording/dataset_limits.h, the
    stage table) and now and then beyond it: about half the datasets are legal throughout."""
    return {
        "slider_mass_kg": pick(rng, -6, 3),
        "counter_mass_kg": pick(rng, -6, 3),
        "stiffness_n_m": pick(rng, 2, 12),
        "stroke_m": pick(rng, -9, -3),
        "freqs_hz": [pick(rng, 0, 6, 3.5) for _ in range(rng.randint(1, 2))],
        "duties": [rng.choice([0.05, 0.25, 0.5, 0.75, 0.95, rng.uniform(0.01, 0.99),
                               rng.uniform(-0.5, 1.5)]) for _ in range(rng.randint(1, 2))],
        "cycles": rng.choice([1, 2, 6, 12, 40, 1000, 100000, 100001, 0, -3]),
        "sample_rate_hz": pick(rng, 2, 8, 1.5),
        "trials": rng.choice([2, 3, 3, 4, 5]),
    }


def number(v):
    return repr(v) if math.isfinite(v) else ("nan" if math.isnan(v) else ("inf" if v > 0 else "-inf"))


def write_dataset(root, v, rng):
    """A dataset of v's values: trial files of 50-2000 samples over the burst and a period either
    side (a constant slider with noise: whether it moves does not matter here)."""
    os.makedirs(os.path.join(root, "trials"))
    with open(os.path.join(root, "stage.yaml"), "w") as f:
        f.write("stage:\n")
        for key in ("slider_mass_kg", "counter_mass_kg", "stiffness_n_m", "stroke_m"):
            f.write(f"  {key}: {number(v[key])}\n")
        f.write("  friction_coefficient: 0.4\n  gravity_m_s2: 9.8\n  step_correction: 0.35\n")
        f.write("interferometer:\n  resolution_m: 9.8906e-9\n")
    rows = ["trial,freq_hz,duty,stroke_m,cycles,sample_rate_hz,guide_pos_m,file"]
    stroke = v["stroke_m"] if math.isfinite(v["stroke_m"]) else 2e-5
    for fi, f_hz in enumerate(v["freqs_hz"]):
        for di, duty in enumerate(v["duties"]):
            for t in range(v["trials"]):
                name = f"c{fi}_{di}_t{t}"
                rows.append(f"{name},{number(f_hz)},{duty!r},{number(v['stroke_m'])},{v['cycles']},"
                            f"{number(v['sample_rate_hz'])},0.01,trials/{name}.csv")
                rate = v["sample_rate_hz"] if math.isfinite(v["sample_rate_hz"]) and \
                    v["sample_rate_hz"] > 0 else 1e4
                period = 1 / f_hz if math.isfinite(f_hz) and f_hz > 0 else 1e-3
                span = (abs(v["cycles"]) + 2) * period  # the burst and a period either side
                n = max(50, min(2000, int(min(span * rate, 1e9))))
                with open(os.path.join(root, "trials", name + ".csv"), "w") as tf:
                    tf.write("t_s,xi_cmd_m,x_m\n")
                    for k in range(n):
                        ts = -period + k * (span + period) / n
                        tf.write(f"{ts!r},{stroke * 0.5!r},{0.01 + rng.gauss(0, 3e-9)!r}\n")
    with open(os.path.join(root, "sweep.csv"), "w") as f:
        f.write("\n".join(rows) + "\n")


def limit_memory():
    resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE_BYTES, ADDRESS_SPACE_BYTES))


@pytest.mark.skipif(not IDM_GAP, reason="IDM_GAP (the idm-gap binary) not set")
@pytest.mark.parametrize("run", range(RUNS))
def test_diagnoses_or_refuses_with_one_line_naming_the_file(run, tmp_path):
    rng = random.Random(SEED + run)
    values = draw(rng)
    dataset = str(tmp_path / "sweep")
    write_dataset(dataset, values, rng)
    try:
        r = subprocess.run([IDM_GAP, "diagnose", dataset, "--effects", "amplifier,stribeck",
                            "--threads", "1"], capture_output=True, text=True,
                           timeout=TIME_LIMIT_S, preexec_fn=limit_memory)
    except subprocess.TimeoutExpired:
        pytest.fail(f"no answer within {TIME_LIMIT_S} s: {values}")
    said = r.stdout + r.stderr
    assert "bad_alloc" not in said, (values, said)
    assert r.returncode in (0, 2), (r.returncode, values, said)
    if r.returncode == 0:
        assert "diagnosis: " in r.stdout, (values, said)
        for line in r.stderr.splitlines():  # only warnings, each naming a trial file
            assert line.startswith("idm-gap diagnose: warning: trial left out: " + dataset), line
    else:
        lines = r.stderr.splitlines()
        assert len(lines) == 1 and r.stdout == "", (values, said)
        assert lines[0].startswith("idm-gap diagnose: " + dataset), (values, lines[0])
