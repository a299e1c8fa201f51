#!/usr/bin/env python3
"""A sweep dataset as another lab's software would write it, for testing idm-gap on files it did
not write itself. Python's standard library only; the physics from docs/model.md, written
again here without the project's code (checked against the paper's reference vectors: --selftest).

The stage is the rigid impulse model: slider mass M, counter mass m, r = m / (M + m).
* Ideal (no amplifier): event-exact. At every corner of the commanded triangle the actuator's
  velocity jumps by dv and the slider's by -r dv; between corners a moving slider decelerates at
  mu g towards rest and stays there. The position is evaluated in closed form at each sample time.
* With amp_fc_hz: a first-order low-pass between the command and the actuator. The command's
  velocity is constant within a phase, so the actuator's relaxes exactly,
  va(t + h) = vc + (va - vc) exp(-wc h); each phase is cut into substeps of at most dt_s that end
  on its corners. Per substep the slider's velocity takes -r times the actuator's change, then
  Coulomb friction (static = kinetic mu) takes mu g h off or holds it at rest; the position is
  advanced by the trapezoid rule and sampled by linear interpolation.
Reading: x_m = round((guide_pos + x_offset + X + N(0, noise)) / res) * res; xi_cmd_m is the
commanded triangle (0 -> S in duty T, S -> 0 in (1 - duty) T), 0 at rest.

The layout quirks a spec-following reader must take (docs/sweep-dataset.md): another column order
with extra columns, text trial ids, nested and ./-prefixed paths, shuffled rows, quoted fields with
commas, CRLF line ends, no final newline, a BOM, upper-case exponents, cycles written 12.0, a
minimal stage.yaml with unknown keys, rows without rest, a sampling grid off t = 0, mixed rates,
and cells with unequal numbers of trials."""
import argparse
import bisect
import math
import os
import random
import sys

G_M_S2 = 9.8


def corners(freq_hz, duty, stroke_m, cycles):
    """(time, actuator velocity jump) at every corner of the commanded triangle."""
    period = 1.0 / freq_hz
    v_extend, v_retract = stroke_m / (duty * period), -stroke_m / ((1 - duty) * period)
    events = [(0.0, v_extend)]
    for k in range(cycles):
        events.append((k * period + duty * period, v_retract - v_extend))
        events.append(((k + 1) * period, (v_extend - v_retract) if k < cycles - 1 else -v_retract))
    return events


def triangle(t, freq_hz, duty, stroke_m, cycles):
    period = 1.0 / freq_hz
    if t <= 0 or t >= cycles * period:
        return 0.0
    tau = max(0.0, t - math.floor(t * freq_hz) * period)
    if tau <= duty * period:
        return stroke_m * tau / (duty * period)
    return stroke_m * (period - tau) / ((1 - duty) * period)


class IdealStage:
    """The event-exact ideal impulse model; position(t) in metres."""

    def __init__(self, M, m, mu, freq_hz, duty, stroke_m, cycles):
        r = m / (M + m)
        self.decel = mu * G_M_S2
        self.t0, self.x0, self.v0 = [], [], []
        x, v, previous = 0.0, 0.0, 0.0
        for t, dv in corners(freq_hz, duty, stroke_m, cycles):
            x, v = self._advance(x, v, t - previous)
            v -= r * dv
            self.t0.append(t)
            self.x0.append(x)
            self.v0.append(v)
            previous = t

    def _advance(self, x, v, tau):
        if v == 0.0 or tau <= 0:
            return x, v
        to_rest = abs(v) / self.decel
        sign = 1.0 if v > 0 else -1.0
        if tau >= to_rest:
            return x + v * to_rest - sign * self.decel * to_rest ** 2 / 2, 0.0
        return x + v * tau - sign * self.decel * tau ** 2 / 2, v - sign * self.decel * tau

    def position(self, t):
        if t <= 0:
            return 0.0
        i = bisect.bisect_right(self.t0, t) - 1
        return self._advance(self.x0[i], self.v0[i], t - self.t0[i])[0]


class AmplifierStage:
    """A first-order amplifier (cutoff amp_fc_hz) in front of the rigid slider, integrated."""

    def __init__(self, M, m, mu, freq_hz, duty, stroke_m, cycles, amp_fc_hz, t_end_s, dt_s):
        r = m / (M + m)
        decel = mu * G_M_S2
        wc = 2 * math.pi * amp_fc_hz
        period = 1.0 / freq_hz
        v_extend, v_retract = stroke_m / (duty * period), -stroke_m / ((1 - duty) * period)
        phases = []
        for k in range(cycles):
            phases.append((k * period, k * period + duty * period, v_extend))
            phases.append((k * period + duty * period, (k + 1) * period, v_retract))
        phases.append((cycles * period, max(t_end_s, cycles * period + dt_s), 0.0))
        self.ts, self.xs = [0.0], [0.0]
        x = v = va = 0.0
        for start, end, vc in phases:
            n = max(1, int(math.ceil((end - start) / dt_s - 1e-9)))
            h = (end - start) / n
            relax = math.exp(-wc * h)
            dv_friction = decel * h
            for i in range(1, n + 1):
                va_next = vc + (va - vc) * relax
                v_before = v
                v -= r * (va_next - va)
                va = va_next
                if v > dv_friction:
                    v -= dv_friction
                elif v < -dv_friction:
                    v += dv_friction
                else:
                    v = 0.0
                x += 0.5 * (v_before + v) * h
                self.ts.append(start + i * h)
                self.xs.append(x)

    def position(self, t):
        if t <= 0:
            return 0.0
        i = bisect.bisect_right(self.ts, t) - 1
        if i >= len(self.ts) - 1:
            return self.xs[-1]
        t0, t1 = self.ts[i], self.ts[i + 1]
        return self.xs[i] + (self.xs[i + 1] - self.xs[i]) * (t - t0) / (t1 - t0)


def selftest(vectors_csv):
    """(worst error of the event-exact model against the paper's reference positions in m,
    worst difference between the integrator with a 1 GHz amplifier and the event-exact model)."""
    M, m, mu, stroke_m = 0.16557, 0.05761, 0.4, 20.35e-6  # Table 1
    worst = 0.0
    with open(vectors_csv) as fh:
        for line in fh:
            if line.startswith("#") or line.startswith("freq"):
                continue
            p = line.strip().split(",")
            f, d = float(p[0]), float(p[1])
            stage = IdealStage(M, m, mu, f, d, stroke_m, 6)
            for k in range(4):
                worst = max(worst, abs(stage.position((k + 1) / f) - float(p[6 + k])))
    worst_integrated = 0.0
    for f, d in [(600, 0.1), (300, 0.4), (500, 0.7), (150, 0.2)]:
        ideal = IdealStage(0.2, 0.07, 0.4, f, d, 15e-6, 12)
        amp = AmplifierStage(0.2, 0.07, 0.4, f, d, 15e-6, 12, 1e9, 13 / f, 1e-6)
        worst_integrated = max(worst_integrated, max(
            abs(ideal.position(k / f) - amp.position(k / f)) for k in range(1, 13)))
    return worst, worst_integrated


def write_sweep(out, seed=1, M=0.2, m=0.07, mu=0.4, strokes_m=(15e-6,), alpha=1.0,
                freqs_hz=(150, 250, 350, 450, 600), duties=(0.1, 0.15, 0.2, 0.3, 0.4), trials=3,
                trials_min=0, cycles=12, cycles_choice=(), rates_hz=(20000,), noise_m=2e-9,
                resolution_m=5e-9, amp_fc_hz=0.0, dt_s=2.5e-7, no_rest=False, grid_offset=0.0,
                x_offset_m=0.0, foreign_layout=False, quoted_notes=False, minimal_yaml=False,
                crlf=False, no_final_newline=False, sci_upper=False, cycles_float=False, bom=False):
    """Writes the dataset to `out`; returns {(freq, duty, stroke): trials} of the cells written."""
    rng = random.Random(seed)
    os.makedirs(out, exist_ok=True)
    nl = "\r\n" if crlf else "\n"

    def write(path, lines, drop_final_newline):
        text = nl.join(lines) + nl
        if drop_final_newline:
            text = text[:-len(nl)]
        with open(path, "w", newline="") as fh:
            if bom and path.endswith("sweep.csv"):
                fh.write("\ufeff")
            fh.write(text)

    rows, cells, index = [], {}, 0
    number = "%.10E" if sci_upper else "%g"
    for stroke in strokes_m:
        for f in freqs_hz:
            for d in duties:
                n_trials = trials if trials_min <= 0 else rng.randint(trials_min, trials)
                cells[(f, d, stroke)] = n_trials
                for k in range(n_trials):
                    index += 1
                    rate = rates_hz[0] if len(rates_hz) == 1 else rng.choice(rates_hz)
                    guide = rng.uniform(0.002, 0.038) + x_offset_m
                    n_cycles = int(rng.choice(cycles_choice)) if cycles_choice else cycles
                    period = 1 / f
                    if no_rest:
                        # from the grid's first point to the first at or after the burst's end
                        k0 = 0
                        k1 = int(math.ceil(n_cycles * period * rate - grid_offset - 1e-9))
                    else:
                        k0 = -int(round(period * rate))
                        k1 = int(math.ceil((n_cycles + 2) * period * rate))
                    times = [(j + grid_offset) / rate for j in range(k0, k1 + 1)]
                    if amp_fc_hz > 0:
                        stage = AmplifierStage(M, m, mu, f, d, stroke, n_cycles, amp_fc_hz,
                                               times[-1] + 1e-6, dt_s)
                    else:
                        stage = IdealStage(M, m, mu, f, d, stroke, n_cycles)
                    if foreign_layout:
                        trial = "run-%02d%s" % (index, "abcdefgh"[k])
                        name = "data/raw/t%02d.csv" % index
                    else:
                        trial = "f%g_d%g_s%g_t%d" % (f, d, stroke, k)
                        name = "trials/%s.csv" % trial
                    if quoted_notes:
                        name = "./" + name
                    os.makedirs(os.path.dirname(os.path.join(out, name)), exist_ok=True)
                    lines = ["t_s,xi_cmd_m,x_m"]
                    for t in times:
                        x = guide + alpha * stage.position(t) + rng.gauss(0, noise_m)
                        x = round(x / resolution_m) * resolution_m
                        xi = triangle(t, f, d, stroke, n_cycles)
                        if sci_upper:
                            lines.append("%.10E,%.10E,%.15E" % (t, xi, x))
                        else:
                            lines.append("%r,%r,%.15g" % (float(t), float(xi), x))
                    write(os.path.join(out, name), lines, no_final_newline and index % 2 == 0)
                    rows.append(dict(trial=trial, freq_hz=number % f, duty=number % d,
                                     stroke_m=number % stroke,
                                     cycles=("%.1f" % n_cycles) if cycles_float else str(n_cycles),
                                     sample_rate_hz=number % rate,
                                     guide_pos_m=("%.10E" if sci_upper else "%.10g") % guide,
                                     file=name, operator="cw", notes="humidity 41pct"))
    columns = ["trial", "freq_hz", "duty", "stroke_m", "cycles", "sample_rate_hz", "guide_pos_m",
               "file"]
    if foreign_layout:
        columns = ["file", "operator", "guide_pos_m", "trial", "notes", "cycles", "duty",
                   "sample_rate_hz", "stroke_m", "freq_hz"]
        rng.shuffle(rows)
    lines = [",".join(columns)] + [",".join(r[c] for c in columns) for r in rows]
    if quoted_notes:
        lines[0] += ",remark"
        for i in range(1, len(lines)):
            lines[i] += ',"slow drift, re-zeroed at %d:0%d ""ok"""' % (9 + i % 3, i % 10)
    write(os.path.join(out, "sweep.csv"), lines, no_final_newline)
    if minimal_yaml:
        yaml = ["# written by another lab's software", "lab:", '  name: "elsewhere"',
                "  operators: [cw, jk]", "stage:", "  model_name: IDM-2   # a key idm has not",
                "  slider_mass_kg: %.3f" % M, "  counter_mass_kg: %.3f" % m,
                "  friction_coefficient: %.2f" % mu, "  gravity_m_s2: 9.80",
                "  stroke_m: %.3e" % strokes_m[0], "  step_correction: 1.00",
                "  guide:", "    length_m: 0.040", "interferometer:", "  head: HP 5517C",
                "  resolution_m: %.3e" % resolution_m]
    else:
        yaml = ["stage:", "  slider_mass_kg: %g" % M, "  counter_mass_kg: %g" % m,
                "  friction_coefficient: %g" % mu, "  gravity_m_s2: %g" % G_M_S2,
                "  stroke_m: %g" % strokes_m[0], "  step_correction: 1",
                "  stiffness_n_m: 5.7e6", "  damping_n_s_m: 230", "interferometer:",
                "  resolution_m: %g" % resolution_m]
    with open(os.path.join(out, "stage.yaml"), "w", newline="") as fh:
        fh.write(nl.join(yaml) + nl)
    return cells


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out", nargs="?")
    ap.add_argument("--selftest", metavar="VECTORS_CSV",
                    help="check the model against tests/data/impulse-model-vectors.csv")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--amp-fc", type=float, default=0.0)
    ap.add_argument("--trials", type=int, default=3)
    ap.add_argument("--foreign-layout", action="store_true")
    a = ap.parse_args()
    if a.selftest:
        worst, integrated = selftest(a.selftest)
        print("event-exact model vs reference: worst %.3g m; integrator vs event-exact: %.3g m"
              % (worst, integrated))
        sys.exit(0 if worst < 1e-12 and integrated < 4e-9 else 1)
    if not a.out:
        ap.error("a directory to write the dataset to")
    write_sweep(a.out, seed=a.seed, amp_fc_hz=a.amp_fc, trials=a.trials,
                foreign_layout=a.foreign_layout)


if __name__ == "__main__":
    main()
