"""Relations between config keys, drawn: configs with random values of the keys that bound each
other (the map's frequencies and strokes against each other, the stage's stroke and the output's
reach; the soft limits against the travel and each other; the windows against one interferometer
count; the end-of-travel threshold against a count over its cycles; the ladder's step classes; the
device's reconnect waits), each value within its own range. `idmd --check-config` must exit 2 with
one line naming a broken key, its value and the allowed range exactly when a relation is broken,
and 0 otherwise; the start refuses the same files (exit 2, the same line) before it opens a device.

The relations are restated here from config/README.md, independently of the code:
  control.min_freq_hz   <= min(max_freq_hz, min(output_sample_rate_hz, the DAC's clock) / 4)
  control.min_stroke_m  <= min(max_stroke_m or stage.stroke_m, max_voltage_v / volts_per_m)
  control.soft_lower_m  within stage.travel_m, < soft_upper_m (and soft_upper_m alike)
  control.tolerance_m   0 or >= one count (lambda_vac / (air_index * counts per wavelength))
  control.hold_window_m 0 or >= the move window (tolerance_m, 0: one count)
  control.eot_step_m    0 or > one count / eot_cycles
  control.min_step_counts < final_step_counts
  daq.reconnect_max_s   >= reconnect_min_s

pytest with hypothesis; argv-free: IDMD (the binary) in the environment. CTest: daemon.config_relations.
"""
import atexit
import os
import re
import shutil
import subprocess
import tempfile

from hypothesis import HealthCheck, given, settings, strategies as st

IDMD = os.environ["IDMD"]
LAMBDA = 632.991e-9
COUNTS_PER_WAVELENGTH = {"single_beam_linear": 64, "plane_mirror": 128}
DAC_CLOCK_HZ = 1e6  # devices.NAME.sim.max_sample_rate_hz's default
VOLTS_PER_M = 2.5e5

TMP = tempfile.mkdtemp(prefix="idmd-relations-")
os.mkdir(os.path.join(TMP, "data"))
atexit.register(shutil.rmtree, TMP, True)


def log_uniform(lo, hi):
    return st.floats(min_value=lo, max_value=hi).map(float)


def zero_or(strategy):
    return st.one_of(st.just(0.0), strategy)


@st.composite
def configs(draw):
    """A dict of the drawn values (None: the key left out)."""
    c = {}
    c["optics"] = draw(st.sampled_from(sorted(COUNTS_PER_WAVELENGTH)))
    c["stroke_m"] = draw(log_uniform(1e-6, 5e-5))
    half = draw(log_uniform(1e-4, 1e-2))
    c["travel"] = (-half, half)
    c["max_voltage_v"] = draw(log_uniform(1.0, 20.0))
    c["reconnect_min_s"] = draw(log_uniform(1e-3, 10.0))
    c["reconnect_max_s"] = draw(log_uniform(1e-3, 10.0))
    c["min_freq_hz"] = draw(log_uniform(10.0, 5000.0))
    c["max_freq_hz"] = draw(log_uniform(10.0, 5000.0))
    c["output_sample_rate_hz"] = draw(log_uniform(5e3, 1e5))
    c["min_stroke_m"] = draw(log_uniform(1e-8, 1e-4))
    c["max_stroke_m"] = draw(zero_or(log_uniform(1e-7, 1e-4)))
    limit = st.one_of(st.none(), st.floats(min_value=-2 * half, max_value=2 * half, allow_subnormal=False))
    c["soft_lower_m"] = draw(limit)
    c["soft_upper_m"] = draw(limit)
    c["tolerance_m"] = draw(zero_or(log_uniform(1e-9, 1e-7)))
    c["hold_window_m"] = draw(zero_or(log_uniform(1e-9, 2e-7)))
    c["eot_step_m"] = draw(zero_or(log_uniform(1e-11, 1e-8)))
    c["eot_cycles"] = draw(st.integers(min_value=1, max_value=100))
    c["final_step_counts"] = draw(st.floats(min_value=0.5, max_value=3.0))
    c["min_step_counts"] = draw(st.floats(min_value=0.0, max_value=2.999, allow_subnormal=False))
    return c


def broken(c):
    """The keys whose relation the values break: {key: value}."""
    out = {}
    count = LAMBDA / (1.0 * COUNTS_PER_WAVELENGTH[c["optics"]])
    if c["reconnect_max_s"] < c["reconnect_min_s"]:
        out["daq.reconnect_max_s"] = c["reconnect_max_s"]
    highest = min(c["max_freq_hz"], min(c["output_sample_rate_hz"], DAC_CLOCK_HZ) / 4)
    if c["min_freq_hz"] > highest:
        out["control.min_freq_hz"] = c["min_freq_hz"]
    largest = min(c["max_stroke_m"] if c["max_stroke_m"] > 0 else c["stroke_m"],
                  c["max_voltage_v"] / VOLTS_PER_M)
    if c["min_stroke_m"] > largest:
        out["control.min_stroke_m"] = c["min_stroke_m"]
    lo, hi = c["travel"]
    lower = lo if c["soft_lower_m"] is None else c["soft_lower_m"]
    upper = hi if c["soft_upper_m"] is None else c["soft_upper_m"]
    if not (lo <= lower <= hi and lower < upper):
        out["control.soft_lower_m"] = lower
    if not (lo <= upper <= hi and upper > lower):
        out["control.soft_upper_m"] = upper
    tol = c["tolerance_m"]
    if tol != 0 and tol < count:
        out["control.tolerance_m"] = tol
    hold = c["hold_window_m"]
    if hold != 0 and hold < (tol if tol > 0 else count):
        out["control.hold_window_m"] = hold
    eot = c["eot_step_m"]
    if eot != 0 and not eot > count / c["eot_cycles"]:
        out["control.eot_step_m"] = eot
    if not c["min_step_counts"] < c["final_step_counts"]:
        out["control.min_step_counts"] = c["min_step_counts"]
    return out


def text(c, name):
    """The config file of `c` (the single-axis form), its paths in this run's directory."""
    control = ""
    for key in ("min_freq_hz", "max_freq_hz", "output_sample_rate_hz", "min_stroke_m",
                "max_stroke_m", "soft_lower_m", "soft_upper_m", "tolerance_m", "hold_window_m",
                "eot_step_m", "eot_cycles", "final_step_counts", "min_step_counts"):
        if c[key] is not None:
            control += "  %s: %r\n" % (key, c[key])
    return (
        "stage:\n  stroke_m: %r\n  travel_m: [%r, %r]\n  step_correction: 1.0\n"
        "interferometer:\n  optics: %s\n  max_velocity_m_s: 1\n"
        "daq:\n  driver: sim\n  reconnect_min_s: %r\n  reconnect_max_s: %r\n"
        "  sim:\n    clock: synthetic\n    max_voltage_v: %r\n    volts_per_m: %r\n"
        "control:\n%s  calibration_file: %s/%s.cal\n"
        "realtime:\n  sched_fifo: false\n  lock_memory: false\n"
        "server:\n  unix_socket: \"\"\n"
        "recording:\n  data_dir: %s/data\n"
        % (c["stroke_m"], c["travel"][0], c["travel"][1], c["optics"], c["reconnect_min_s"],
           c["reconnect_max_s"], c["max_voltage_v"], VOLTS_PER_M, control, TMP, name, TMP))


def write(c, name="drawn"):
    path = os.path.join(TMP, name + ".yaml")
    with open(path, "w") as f:
        f.write(text(c, name))
    return path


def check_refusal(r, path, bad):
    """`r` (a finished idmd) refused `path` in one line naming one of `bad`'s keys, its value and
    the allowed range."""
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr, bad)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    m = re.search(re.escape(path) + r":\d+: (\S+): (\S+) is out of range, allowed (.+)$", lines[0])
    assert m, lines[0]
    key, value = m.group(1), float(m.group(2))
    assert key in bad, (lines[0], bad)
    assert abs(value - bad[key]) <= 1e-8 * abs(bad[key]), (lines[0], bad)
    assert re.search(r"^(0 or )?[\[(<>]|^none \(|^0 only \(", m.group(3)), lines[0]


@settings(max_examples=int(os.environ.get("IDM_RELATION_EXAMPLES", "150")), deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(configs())
def test_check_config_refuses_exactly_the_broken_relations(c):
    path = write(c)
    r = subprocess.run([IDMD, "--check-config", path], capture_output=True, text=True, timeout=60)
    bad = broken(c)
    if bad:
        check_refusal(r, path, bad)
    else:
        assert r.returncode == 0, (r.stderr, c)
        assert "warning" not in r.stderr, r.stderr


# Each relation broken alone, from a config that breaks none: --check-config and the start refuse
# it naming that key (the start before it opens a device: the simulated stage here).
GOOD = {"optics": "single_beam_linear", "stroke_m": 2.035e-5, "travel": (-1e-3, 1e-3),
        "max_voltage_v": 10.0, "reconnect_min_s": 0.05, "reconnect_max_s": 2.0,
        "min_freq_hz": 10.0, "max_freq_hz": 2000.0, "output_sample_rate_hz": 1e5,
        "min_stroke_m": 1e-7, "max_stroke_m": 0.0, "soft_lower_m": None, "soft_upper_m": None,
        "tolerance_m": 0.0, "hold_window_m": 0.0, "eot_step_m": 2e-9, "eot_cycles": 20,
        "final_step_counts": 2.0, "min_step_counts": 0.3}
ALONE = [
    ("control.min_stroke_m", {"min_stroke_m": 3e-5}),            # above the stage's stroke
    ("control.min_stroke_m", {"min_stroke_m": 5e-6, "max_stroke_m": 4e-6}),
    ("control.min_stroke_m", {"min_stroke_m": 1e-5, "max_voltage_v": 2.0}),  # reach 8 um
    ("control.min_freq_hz", {"min_freq_hz": 3000.0}),
    ("control.min_freq_hz", {"min_freq_hz": 1500.0, "output_sample_rate_hz": 4000.0}),
    ("control.soft_upper_m", {"soft_upper_m": 2e-3}),
    ("control.soft_lower_m", {"soft_lower_m": 5e-4, "soft_upper_m": 5e-4}),
    ("control.tolerance_m", {"tolerance_m": 5e-9}),
    ("control.hold_window_m", {"tolerance_m": 5e-8, "hold_window_m": 3e-8}),
    ("control.eot_step_m", {"eot_step_m": 4e-10}),
    ("control.min_step_counts", {"min_step_counts": 2.0}),
    ("daq.reconnect_max_s", {"reconnect_max_s": 0.01}),
]


def test_each_relation_alone_at_check_and_at_start():
    path = write(GOOD, "good")
    r = subprocess.run([IDMD, "--check-config", path], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and not r.stderr, r.stderr
    for i, (key, edits) in enumerate(ALONE):
        c = dict(GOOD, **edits)
        assert key in broken(c), (key, broken(c))
        path = write(c, "alone%d" % i)
        r = subprocess.run([IDMD, "--check-config", path], capture_output=True, text=True,
                           timeout=60)
        check_refusal(r, path, broken(c))
        checked = r.stderr
        r = subprocess.run([IDMD, "--config", path, "--port", "0", "--unix", ""],
                           capture_output=True, text=True, timeout=60)
        check_refusal(r, path, broken(c))
        assert r.stderr == checked, (r.stderr, checked)
