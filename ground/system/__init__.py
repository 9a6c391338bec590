"""``fps system``: the whole terminal in one run, the ADCS loop and the fine-pointing loop coupled live.

- The ADCS loop (``--adcs``) runs ahead in its own process (``multiprocessing``, spawn) and sends one message
  per 1 s cycle: ``firmware``, the ADCS flight software on CAN against the emulated spacecraft
  (``emulator.adcs_session.AdcsSession``), or ``ground``, the body pointing simulator of Sec. 6.4
  (``ground.adcs.body_pointing.simulate``, run whole and sent in 1 s slices; its results are those of
  ``fps adcs bps``: in the thesis world the truth, 41-state APKF, STKF with the EAFLS and the controller; in the
  flight world the flight app itself in process, bit for bit the firmware's history). Of each cycle's ten 0.1 s truth samples the
  body pointing error (dtheta1, dtheta2 about the laser line of sight, Eq. 6.12-6.16) and the stability
  (Eq. 6.18-6.21) are taken by ``ground.adcs.body_pointing.pointing_errors``; the flight software's estimates ("est")
  are compared with the truth at the cycle's start.
- The fine-pointing loop runs as ``fps hil`` does (``ground.hil``: the bench in lockstep with the controller
  firmware over serial, ``micropython`` or ``cpython``, at 637.8 Hz; H calibration, Q2 calibration, Q2
  recorder), but its disturbance player is live: from the start of the collection window (after the ADCS's
  30 s hold and 4 t_s of settling, t = 0 of the play) the 10 Hz dtheta are resampled to the 8.192 ms distfile
  step by 3rd-order Lagrange interpolation (Sec. 7.3.1, ``ground.resample``: the same samples ``fps distfile
  generate --source bps`` would write) and appended to an in-memory distfile that ``firmware.player.Player``
  plays (Keys's 6-point cubic interpolation, Eq. 7.7-7.8 to AD660 codes at 10.6 kHz). A sample beyond the P-FSM's
  +-3 deg / 13.33 (a bench limit) is played at the range's edge, counted, and its window is an outage of the
  availability (``ground.availability``); the run goes on.
- Coupling and timing: before each 1 s chunk of the fine loop the main process takes ADCS messages until the
  disturbance is known to the chunk's end (plus the interpolation stencil); the ADCS process is ahead, so the
  two loops overlap on two cores. The body pointing reaches the P-FSM with no other delay.

- One verdict for the terminal (``verdict``): the fine loop (every Q2 sample within 11.98″) and the body loop
  (3σ pointing <= 150″, stability <= 35″/s); exit 0 only when the run completed and both are met, 3 when it
  completed and a budget was missed.
- Failures end the run within a bound: the ADCS process sends a heartbeat every ``HEARTBEAT_S`` and is declared
  stopped after ``SILENT_S`` without a message; ``AdcsFeed.close`` asks it to stop, then SIGTERMs, then SIGKILLs
  it (``STOP_S``), reading its queue meanwhile so that its writer never blocks the exit.

Run folder (atomic writes): ``config.json``, ``calibration.json``, ``q2_calibration.json``, ``telemetry.csv``,
``samples.npz`` (as ``fps hil``), ``body.npz`` (10 Hz dtheta, domega and estimate errors), ``summary.json``
(``complete`` false until the end; ``verdict``; a stopped run's ``error`` and ``stopped_in``, the phase it was
in), ``report.md`` and ``system_pointing.png`` (both pointing errors on one time axis); a failure, Ctrl-C or
SIGTERM leaves the folder valid with ``complete: false``.

The parts, one idea a module: ``constants``; ``live`` (the live disturbance); ``adcs`` (the ADCS process and its
feed); ``run`` (``run_system``, the run folder); ``reporting`` (the verdict, report.md, the figure); ``cli``.
Their names are all here too (``ground.system.run_system``).
"""


from ground.system.constants import (  # noqa: F401
    ADCS_KINDS, FIGURE, RUNTIMES, LEAD_S, STENCIL_S, WAIT_S,
    HEARTBEAT_S, SILENT_S, START_S, STOP_S, GOAL_RTF, firmware_available)
from ground.system.live import (  # noqa: F401
    LiveDistfile, LiveDisturbance)
from ground.system.adcs import (  # noqa: F401
    settle_s, estimation_accuracy, _Stopped, _vehicle, _ground_run, _reference,
    _t_settle, _send_ground, _send_firmware, _jsonable, StopFlag, _heartbeat,
    adcs_worker, AdcsFeed, _signals_held)
from ground.system.run import (  # noqa: F401
    check_inputs, calibrate_inproc, run_system, _stopped_folder, _body_summary)
from ground.system.reporting import (  # noqa: F401
    verdict, _over, exit_code, verdict_lines, verdict_md, thesis_body,
    _plot, _f, side_by_side, _hold_s, report_md, _cell,
    wheel_names, adcs_session_md, _x)
from ground.system.cli import (  # noqa: F401
    _read_summary, _link_faults_arg, _cmd, EXIT_STATUS, register)
