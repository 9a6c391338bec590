"""Issue 12: the loop's frequency response (``fps response``) at the default board timing and at zero latency.

Prints, per timing, the measured |S| and phase beside the model (ground.response.LoopModel) from 1 Hz to 0.4x the
loop's Nyquist frequency, the margins and bandwidth, the 12/35/55 Hz tones beside the model with delay, and the
wall time of 30 tones in-process (goal <= 60 s)."""

import tempfile
import time

import numpy as np

from emulator.config import default_config
from ground.response import LoopModel, run_response


def main():
    print("## fps response (issue 12)\n")
    for timing in ("arduino-zero", "zero-latency"):
        cfg = default_config()
        cfg["board"]["timing"] = timing
        with tempfile.TemporaryDirectory() as d:
            t0 = time.perf_counter()
            s = run_response(d, cfg, 1.0, 300.0, 30, quiet=True, plots=False)
            wall = time.perf_counter() - t0
        f = np.array(s["freq_hz"])
        band = f <= 0.4 * 637.8 / 2
        err = np.abs(np.array(s["s_measured"]) / np.array(s["s_model"]) - 1)[band]
        dph = np.abs(np.array(s["phase_measured_deg"]) - np.array(s["phase_model_deg"]))[band]
        print("| %s timing | goal | ours |" % timing)
        print("|---|---|---|")
        print("| max abs(|S| measured / model - 1), 1 Hz to 0.4 Nyquist | <= 5 %% | %.1f %% (median %.1f %%) |"
              % (100 * err.max(), 100 * np.median(err)))
        print("| max phase error, same band | <= 5 deg | %.1f deg |" % dph.max())
        print("| gain / phase margin, -3 dB rejection bandwidth | thesis: none (Sec. 8.3 future work) | "
              "%.1f dB / %.1f deg / %.1f Hz |" % (s["gain_margin_db"], s["phase_margin_deg"], s["bandwidth_hz"]))
        print("| 30 tones in-process, wall | <= 60 s | %.1f s (%.1f s in the loop) |" % (wall, s["wall_s"]))
        m = LoopModel(cfg)
        tones = np.array([12.0, 35.0, 55.0])
        print("| tones 12/35/55 Hz: model |S| at the samples / on the truth | issue: 0.87 at 55 Hz (zero latency) | "
              "%s / %s |" % (np.round(np.abs(m.s_samples(tones)), 3).tolist(),
                             np.round(np.abs(m.s_truth(tones)), 3).tolist()))
        print()


if __name__ == "__main__":
    main()
