"""``fps response``: the fine-pointing loop's frequency response, measured on the bench and modelled.

The thesis lists this as future work (Sec. 8.3). Stepped sines (X sine, Y cosine, ``--amp`` arcsec on the sky)
go through the P-FSM while the controller firmware tracks; at each frequency the sensitivity S is the complex
ratio of the residual to the input at that frequency, both from the truth at the Q2 instants (the input is
the P-FSM's share of the sky error, Eq. 7.5; the residual the whole sky error), fitted over whole cycles after
the loop settled.

The model (``LoopModel``), per axis with H^-1 H = I (the controller uses the truth's H, or ``--calibration``):
- controller: the integral law V[k] = V[k-1] - g H^-1 dR[k] (Eq. 7.12-7.13), C(z) = g z / (z - 1);
- plant: the MEMS drive filter and mirror (emulator.mirrors.MEMS: 2nd-order Butterworth at
  ``mems.driver_cutoff_hz`` then the resonance), its input held from the words' landing instant L (board
  timing, emulator.timing) and sampled at the axis's channel instant tau: P(z) is the exact discretisation with
  the fractional delay D = L - tau (modified z-transform: the state sees u[k-d-1] for eps, u[k-d] for T - eps,
  D = d T + eps);
- S_d(z) = 1 / (1 + C P) at the samples; the residual's component at f on the continuous truth is
  S(f) = 1 - C S_d Gm(j w) ZOH(w) exp(-j w D), ZOH(w) = (1 - exp(-j w T)) / (j w T) (the fundamental of the
  held, filtered command; derived here, no thesis equation).
python-control gives the Bode data and the phase margin of the loop C P; the gain margin is the largest stable
gain scale (bisection on the closed-loop poles) and S_d's -3 dB bandwidth a scan of |S_d|.

A run stopped by Ctrl-C or SIGTERM (exit 130), or failing (exit 1), leaves summary.json with ``complete`` false,
``interrupted``, the error (naming the controller's process and how it ended, when it died) and the tones measured
so far.
"""

import math

import numpy as np
from scipy.linalg import expm

from emulator.mirrors import MEMS
from emulator.timing import board_timing

AXES = ("x", "y")
FIGURES = ("bode_sensitivity.png", "bode_loop.png")


class LoopModel:
    """The loop of one axis (0 = X, 1 = Y) for a bench config, tick rate and gain g (see the module)."""

    def __init__(self, cfg, rate_hz=637.8, gain=0.5, axis=0):
        import control
        self.control = control
        self.T = T = 1.0 / rate_hz
        self.gain = gain
        tm = board_timing(cfg)
        tm.split(T)                              # refuses a tick shorter than the reads
        self.tau = tm.sample_s[axis]
        self.D = tm.land_s - self.tau            # sample to landing
        d = int(self.D // T + 1e-12)
        eps = self.D - d * T
        if eps < 1e-12 * T:
            eps = 0.0
        modal = MEMS(cfg).modal
        self.mems = modal
        a, b, c = modal.a, modal.b_ss.reshape(-1, 1), modal.c_ss.reshape(1, -1)
        n = a.shape[0]

        def phi_gam(t):
            m = np.zeros((n + 1, n + 1))
            m[:n, :n], m[:n, n:] = a * t, b * t
            e = expm(m)
            return e[:n, :n], e[:n, n:]

        phi, _ = phi_gam(T)
        ph_a, gam_a = phi_gam(T - eps)          # input u[k-d] over the last T - eps of the interval
        _, gam_e = phi_gam(eps)
        g1 = ph_a @ gam_e                        # u[k-d-1] over the first eps
        z1 = control.tf([1], [1, 0], T)
        p = control.ss(phi, gam_a, c, 0, T)
        if eps > 0:
            p = p + control.ss(phi, g1, c, 0, T) * z1
        p = control.tf(p)
        for _ in range(d):
            p = p * z1
        self.P = control.minreal(p, verbose=False)
        self.C = control.tf([gain, 0], [1, -1], T)
        self.L = self.C * self.P
        self.S = control.feedback(1, self.L)

    def s_samples(self, f_hz):
        """S_d at the controller's samples (complex)."""
        return np.asarray(self.control.frequency_response(self.S, 2 * np.pi * np.atleast_1d(f_hz)).complex)

    def s_truth(self, f_hz):
        """S on the continuous truth at f (the residual's component at f over the input's), complex."""
        f = np.atleast_1d(np.asarray(f_hz, float))
        w = 2 * np.pi * f
        T = self.T
        zc = self.control.frequency_response(self.C, w).complex
        sd = self.s_samples(f)
        gm = np.array([self.mems.response(x) for x in f])
        zoh = (1 - np.exp(-1j * w * T)) / (1j * w * T)
        return 1 - zc * sd * gm * zoh * np.exp(-1j * w * self.D)

    def stable(self, k=1.0):
        """Whether the loop with its gain scaled by k is stable (closed-loop poles inside the unit circle)."""
        return bool(np.all(np.abs(self.control.poles(self.control.feedback(1, k * self.L))) < 1.0))

    def margins(self):
        """(gain margin dB, phase margin deg) of the loop C P: the phase margin from python-control's
        stability_margins; the gain margin as the largest stable gain scale (bisection on the closed-loop
        poles), since a phase crossover at the Nyquist frequency itself is not reported by stability_margins."""
        _, pm, _, _, _, _ = self.control.stability_margins(self.L)
        lo, hi = 1.0, 2.0
        if not self.stable(1.0):
            return float("-inf"), float(pm)
        while self.stable(hi) and hi < 1e4:
            lo, hi = hi, 2 * hi
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if self.stable(mid) else (lo, mid)
        return 20 * math.log10(lo), float(pm)

    def bandwidth_hz(self):
        """-3 dB rejection bandwidth: the lowest frequency where |S_d| rises to 1/sqrt(2)."""
        nyq = 0.5 / self.T
        f = np.logspace(-1, math.log10(nyq * 0.999), 4000)
        s = np.abs(self.s_samples(f))
        i = int(np.argmax(s >= 2 ** -0.5))
        if s[i] < 2 ** -0.5:
            return float("nan")
        f0, f1, s0, s1 = f[i - 1], f[i], s[i - 1], s[i]
        return float(f0 + (2 ** -0.5 - s0) * (f1 - f0) / (s1 - s0))


def fit_tone(t, y, f_hz, others=()):
    """Complex amplitude of the tone at f in samples y(t) (least squares with an offset), fitted together with
    tones at ``others`` (Hz) that would leak into it over a short window."""
    w = 2 * np.pi * f_hz
    cols = [np.cos(w * t), np.sin(w * t), np.ones_like(t)]
    for fo in others:
        cols += [np.cos(2 * np.pi * fo * t), np.sin(2 * np.pi * fo * t)]
    a = np.column_stack(cols)
    sol, *_ = np.linalg.lstsq(a, y, rcond=None)
    return sol[0] - 1j * sol[1]


MIN_FROM_HZ = 0.1        # lowest tone: 4 cycles of it take 40 s of virtual time
MAX_POINTS = 200
MIN_CYCLES = 4
MIN_AMP_ARCSEC = 0.1     # 4 codes of the P-FSM's AD660 (0.025 arcsec on the sky each); 1e-3 rounded to none


def measure(rig, freqs, amp_arcsec=5.0, settle_s=0.1, min_cycles=MIN_CYCLES, min_s=0.25, progress=None, model=None,
            into=None):
    """Play each tone through the P-FSM with the loop in TRACK; return per frequency the complex S of X and
    Y (residual / input from the truth at the Q2 instants): (frequencies played, S). The rig's player is
    restored after. ``into``: a dict whose "freq_hz" and "s" lists get each tone as it is measured (what a run
    stopped halfway keeps).

    With a ``model`` (LoopModel) the amplitude is scheduled: amp / |S_model|, between amp and 3 amp, so the
    residual stays well above the FSM DAC's step (1 AD5664R code ~ 0.02 arcsec on the sky), which otherwise
    biases a small |S| by several per cent."""
    from emulator.lockstep import SinePlayer
    from ground.rig import AD660_CODES_PER_VOLT, PFSM_V_PER_ARCSEC
    b, ls = rig.bench, rig.lockstep
    amp_codes = amp_arcsec * PFSM_V_PER_ARCSEC * AD660_CODES_PER_VOLT
    ksky = b._ang_mag2 * b._sky
    into = {} if into is None else into
    out = into.setdefault("s", [])
    used = into.setdefault("freq_hz", [])
    hold, block0 = ls.player, ls.block_ticks
    try:
        for i, f in enumerate(freqs):
            # the held command's images at rate -+ f, sampled by Q2 at q2_hz, fold to |rate -+ f - q2_hz|: near
            # f = (rate - q2_hz) / 2 (3.9 Hz) one falls on the tone itself. The window is lengthened to resolve
            # it (3 / |f_alias - f|, up to 12 s), and a tone within 0.15 Hz of it is moved 0.3 Hz up.
            def alias(f):
                return abs(rig.rate_hz - f - b.q2_hz)
            if abs(alias(f) - f) < 0.15:
                f = f + 0.3
            n_meas = max(min_cycles / f, min_s, min(12.0, 3.0 / max(abs(alias(f) - f), 1e-9)))
            n_meas = math.ceil(n_meas * f) / f                   # whole cycles
            n_ticks = int(round((settle_s + n_meas) * rig.rate_hz)) + 1
            k = 1.0 if model is None else float(np.clip(1.0 / abs(model.s_truth(f)[0]), 1.0, 3.0))
            ls.player = SinePlayer(amp=amp_codes * k, hz=f, pfsm_hz=ls.pfsm_hz)
            ls.block_ticks = n_ticks                             # one block: the P-FSM tilts at every Q2 instant
            t0 = ls.tick / rig.rate_hz
            res = rig.run(n_ticks)
            m = len(res["truth_arcsec"])
            tq = res["q2"][:, 1] * 1e-6 - t0
            inp = np.column_stack([np.asarray(b.blk.q2_tpx[:m]), np.asarray(b.blk.q2_tpy[:m])]) * ksky
            keep = (tq >= settle_s) & (tq < settle_s + n_meas)
            # the held command's images at rate -+ f, sampled by Q2 at q2_hz, fold to |rate -+ f - q2_hz|
            # (the recorder's aliasing): fit them too where they fall near f
            win = n_meas
            others = [fo for fo in (abs(rig.rate_hz - f - b.q2_hz), abs(rig.rate_hz + f - b.q2_hz))
                      if abs(fo - f) > 0.5 / win and fo > 0.5 / win and fo < 0.5 * b.q2_hz]
            s = []
            for ax in (0, 1):
                a_in = fit_tone(tq[keep], inp[keep, ax], f)
                a_out = fit_tone(tq[keep], res["truth_arcsec"][keep, ax], f, others)
                s.append(a_out / a_in)
            out.append(s)
            used.append(f)
            if progress:
                progress(i + 1)
    finally:
        ls.player, ls.block_ticks = hold, block0
        rig.pfsm_v(0.0, 0.0)
    return np.array(used), np.array(out)


def truth_calibration(cfg, grid=(-1.0, 0.0, 1.0)):
    """A calibration dict (the format of ``fps calibrate``) from the emulator's true H on a small grid."""
    from emulator.bench import Bench
    b = Bench(cfg, noise=False)
    pts = []
    for y in grid:
        for x in grid:
            r = b.true_h((x, y))
            pts.append({"pfsm_v": [x, y], "v0": r["v0"], "H": r["H"], "residual": r["residual"]})
    return {"grid_v": list(grid), "points": pts, "source": "emulator truth"}


def run_response(out_dir, cfg=None, f_from=1.0, f_to=300.0, points=30, runtime_name="inproc", link_name="inproc",
                 calibration=None, amp_arcsec=5.0, seed=0, plots=True, quiet=False, link_opts=None):
    """Measure and model; write summary.json (and the Bode plots) in ``out_dir``. Returns the summary."""
    import os
    import time
    from emulator.config import default_config
    from ground import runtime
    from ground.fileio import write_json
    from protocol import htable
    cfg = default_config() if cfg is None else cfg
    link_opts = dict(link_opts or {})
    from ground import runtime as _rt
    _rt.check_options(runtime_name, link_name, **link_opts)     # --rate-hz and the link's options first, then --to
    rate = link_opts.get("rate_hz", 637.8)
    nyq = rate / 2
    if not MIN_FROM_HZ <= f_from < f_to:
        raise ValueError("--from %g and --to %g: need %g <= from < to Hz (each tone plays %d cycles)"
                         % (f_from, f_to, MIN_FROM_HZ, MIN_CYCLES))
    if f_to >= nyq:
        raise ValueError("--to %g Hz is at or above the loop's Nyquist frequency %g Hz" % (f_to, nyq))
    if not 2 <= points <= MAX_POINTS:
        raise ValueError("--points %d: need 2 to %d" % (points, MAX_POINTS))
    if not MIN_AMP_ARCSEC <= amp_arcsec <= 10:
        raise ValueError("--amp %g: need %g <= amp <= 10 arcsec (at least 4 codes of the P-FSM's DAC; scheduled "
                         "up to 3x where |S| is small, the residual must stay in the quadcell's linear range)"
                         % (amp_arcsec, MIN_AMP_ARCSEC))
    runtime.check_seed(seed)
    freqs = np.geomspace(f_from, f_to, points)
    models = [LoopModel(cfg, rate, 0.5, ax) for ax in (0, 1)]     # refuses a board too slow for the rate
    cal = truth_calibration(cfg) if calibration is None else calibration
    from ground.fileio import run_folder
    run_folder(out_dir, FIGURES)
    timing = board_timing(cfg).as_dict()
    summary = {"complete": False, "timing": timing, "rate_hz": rate, "gain": 0.5, "runtime": runtime_name,
               "link": link_name, "amp_arcsec": amp_arcsec}
    write_json(os.path.join(out_dir, "summary.json"), summary)
    t0 = time.perf_counter()
    bar = None
    if not quiet:
        from tqdm import tqdm
        bar = tqdm(total=len(freqs), unit="tone")
    got, opened = {}, []
    try:
        with runtime.open_rig(runtime_name, link_name, config=cfg, seed=seed, **link_opts) as rig:
            opened.append(rig)
            rig.upload_htable(htable.pack_calibration(cal))
            rig.pfsm_v(0.0, 0.0)
            rig.settings("TRACK", decim=0)
            rig.run(int(0.2 * rig.rate_hz))
            freqs, s = measure(rig, freqs, amp_arcsec, progress=(lambda i: bar.update(1)) if bar else None,
                               model=models[0], into=got)
    except (KeyboardInterrupt, OSError) as exc:
        if isinstance(exc, OSError):           # the run failed: and the controller, if its process ended
            rig = opened[0] if opened else getattr(exc, "rig", None)
            exc = OSError("%s%s" % (exc, runtime.exit_note(getattr(rig, "process", None), wait_s=0.5)))
        _stopped(os.path.join(out_dir, "summary.json"), summary, got, exc, time.perf_counter() - t0)
        if isinstance(exc, OSError):
            raise exc from None
        raise
    finally:
        if bar:
            bar.close()
    wall = time.perf_counter() - t0
    sm = models[0].s_truth(freqs)
    gm, pm = models[0].margins()
    summary.update({
        "complete": True, "wall_s": round(wall, 3), "axis": "x (y in the *_y keys)",
        "freq_hz": freqs.tolist(),
        "s_measured": np.abs(s[:, 0]).tolist(), "s_model": np.abs(sm).tolist(),
        "phase_measured_deg": np.degrees(np.angle(s[:, 0])).tolist(),
        "phase_model_deg": np.degrees(np.angle(sm)).tolist(),
        "s_measured_y": np.abs(s[:, 1]).tolist(), "s_model_y": np.abs(models[1].s_truth(freqs)).tolist(),
        "gain_margin_db": gm, "phase_margin_deg": pm, "bandwidth_hz": models[0].bandwidth_hz()})
    write_json(os.path.join(out_dir, "summary.json"), summary)
    if plots:
        _plot(out_dir, freqs, s[:, 0], models[0], summary)
    return summary


def _stopped(path, summary, got, exc, wall):
    """summary.json of a run stopped by ``exc`` (an interruption or the run failing): complete false, why, and the
    tones measured before (``measure``'s ``into``)."""
    from ground.fileio import write_json
    freqs, s = got.get("freq_hz", []), got.get("s", [])
    n = min(len(freqs), len(s))                   # a tone the interruption cut while it was being recorded
    s = np.array(s[:n], complex).reshape(-1, 2)
    summary.update({"complete": False, "interrupted": isinstance(exc, KeyboardInterrupt), "wall_s": round(wall, 3),
                    "error": None if isinstance(exc, KeyboardInterrupt) else str(exc), "tones_measured": n,
                    "freq_hz": [float(f) for f in freqs[:n]], "s_measured": np.abs(s[:, 0]).tolist(),
                    "phase_measured_deg": np.degrees(np.angle(s[:, 0])).tolist(),
                    "s_measured_y": np.abs(s[:, 1]).tolist()})
    write_json(path, summary)


def _plot(out_dir, freqs, s_meas, model, summary):
    import os
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from ground.plots import save_png
    f = np.geomspace(freqs[0], freqs[-1], 400)
    sm = model.s_truth(f)
    fig, (a1, a2) = plt.subplots(2, 1, sharex=True, figsize=(7, 6))
    a1.semilogx(f, 20 * np.log10(np.abs(sm)), label="model |S| (truth)")
    a1.semilogx(freqs, 20 * np.log10(np.abs(s_meas)), "o", label="measured |S|")
    a1.axhline(-3, ls=":", c="gray", label="-3 dB: the bandwidth where |S| crosses it")
    a1.set_ylabel("|S| (dB)")
    a1.set_title("Sensitivity, X axis, %s timing: GM %.1f dB, PM %.1f deg, -3 dB %.1f Hz"
                 % (summary["timing"]["timing"], summary["gain_margin_db"], summary["phase_margin_deg"],
                    summary["bandwidth_hz"]), fontsize=9)
    a1.legend()
    a2.semilogx(f, np.degrees(np.angle(sm)))
    a2.semilogx(freqs, np.degrees(np.angle(s_meas)), "o")
    a2.set_ylabel("phase (deg)")
    a2.set_xlabel("frequency (Hz)")
    fig.tight_layout()
    save_png(fig, os.path.join(out_dir, FIGURES[0]), dpi=100)
    w = 2 * np.pi * np.geomspace(0.5, 0.499 / model.T, 400)
    fig = plt.figure(figsize=(7, 6))
    L = model.L
    try:
        L = model.control.tf(L, name="L = C(z) P(z)")     # python-control titles a plot by the system's name
    except TypeError:                                      # an older python-control: no name to give
        pass
    model.control.bode_plot(L, w, dB=True, Hz=True, display_margins=True,
                            title="Loop C(z) P(z), X axis, g = %g" % model.gain)
    fig = plt.gcf()
    f_nyq = 0.5 / model.T
    for ax in fig.axes:
        ax.axvline(f_nyq, color="0.4", ls=":", lw=0.8, label="Nyquist frequency %.1f Hz" % f_nyq)
        ax.legend(fontsize=8, loc="lower left")
    save_png(fig, os.path.join(out_dir, FIGURES[1]), dpi=100)
    plt.close("all")


def _cmd(a):
    import os
    from emulator.config import load_config
    from ground import runtime
    if a.timing == "custom" and not a.config:
        raise ValueError("--timing custom takes its numbers (board.adc_read_us and the rest) from a bench config: "
                         "give --config FILE, or use --timing arduino-zero or zero-latency")
    cfg = load_config(a.config)
    if a.timing:
        cfg["board"]["timing"] = a.timing
    cal = None
    if a.calibration:
        from ground.calibrate import load_calibration
        cal = load_calibration(a.calibration)
    s = run_response(a.output, cfg, a.from_hz, a.to_hz, a.points, a.runtime, a.link, cal, a.amp, a.seed,
                     plots=not a.no_plots, quiet=a.quiet, link_opts=runtime.link_options(a))
    lines = table_lines(s)
    print("\n".join(lines))
    from ground import verdict
    from ground.fileio import write_atomic
    worst = max((abs(m - d) / d for m, d in zip(s["s_measured"], s["s_model"]) if d), default=None)
    write_atomic(os.path.join(a.output, "report.md"), "\n".join(
        ["# fps response: the loop's sensitivity |S|, measured beside the model", ""] + verdict.table(
            [("largest relative difference of the measured \\|S\\| from the model's (a measurement: no "
              "requirement, exit 0)", worst, None, None)]) + lines) + "\n")
    verdict.close(a.output)
    return 0


def table_lines(s):
    """The measured |S| and phase beside the model's, per tone, and the margins (report.md and the terminal)."""
    lines = ["| f (Hz) | \\|S\\| measured | \\|S\\| model | phase measured (deg) | phase model (deg) |",
             "|---|---|---|---|---|"]
    for row in zip(s["freq_hz"], s["s_measured"], s["s_model"], s["phase_measured_deg"], s["phase_model_deg"]):
        lines.append("| %.2f | %.3f | %.3f | %.1f | %.1f |" % row)
    lines += ["", "board timing %s (samples at %s us, words land at %.1f us), g = 0.5: gain margin %.1f dB, phase "
              "margin %.1f deg, -3 dB rejection bandwidth %.1f Hz; %d tones in %.3g s wall"
              % (s["timing"]["timing"], s["timing"]["sample_us"], s["timing"]["land_us"], s["gain_margin_db"],
                 s["phase_margin_deg"], s["bandwidth_hz"], len(s["freq_hz"]), s["wall_s"])]
    return lines


def register(sub, name, help_):
    p = sub.add_parser(name, help=help_, description=__doc__.split("\n\n")[0])
    from ground.fileio import output_folder
    from ground.runtime import add_link_arguments
    add_link_arguments(p)
    p.add_argument("--config", help="bench config JSON (default: the thesis bench preset)")
    p.add_argument("--timing", choices=("arduino-zero", "zero-latency", "custom"),
                   help="override the config's board timing (emulator.timing)")
    p.add_argument("--calibration", help="H calibration JSON to upload (default: the emulator's true H)")
    p.add_argument("--from", dest="from_hz", type=float, default=1.0, help="lowest tone, Hz (default 1)")
    p.add_argument("--to", dest="to_hz", type=float, default=300.0, help="highest tone, Hz (default 300)")
    p.add_argument("--points", type=int, default=30, help="tones, log-spaced (default 30)")
    p.add_argument("--amp", type=float, default=5.0, help="tone amplitude, arcsec on the sky (default 5)")
    p.add_argument("--seed", type=int, default=0, help="the emulator's seed, >= 0 (default 0)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--no-plots", action="store_true")
    p.add_argument("-o", "--output", required=True, type=output_folder, help="run folder")

    def func(a):
        from ground.runtime import default_link
        default_link(a)
        return _cmd(a)
    p.set_defaults(func=func)
