"""The clock: lockstep (virtual time) and real-time runs of the bench against a controller and a player.

Per control tick k (t = k / rate_hz): the bench's Q1 sample goes to the controller, whose answer (AD5664R words)
is applied to the MEMS driver, then the physics advances one tick with the P-FSM taking the player's codes at
its own rate. A controller that answers nothing (None or empty) or too late is a counted overrun and the mirror
holds its last input, as the hardware would. In real-time mode tick k starts at wall time t0 + k / rate_hz and an
answer later than ``deadline_s`` after that is an overrun (its words are dropped).

The player is open loop, so its codes are fetched ``block_ticks`` ticks at a time (one ``fill`` call) and the
P-FSM input sums precomputed per block; ``block_ticks=1`` interleaves player and controller exactly. In virtual
time without ``on_q2`` the ticks of a block run in one ``Bench.run_ticks`` call (the fast path); real time and
``on_q2`` go tick by tick.

The board's timing (``emulator.timing``, the bench config's ``board``) decides when within tick k each Q1 channel
is sampled and when the answer's words act: at their modelled instant inside tick k or a later tick (the thesis's
board: just inside tick k + 1). It is deterministic: the words of tick k always land at the same instant, whatever
the link's retries. ``zero-latency`` samples at the tick start and applies the words at once.

Duck types (docs/INTERFACES.md): ``controller.on_tick(tick, t_us, vx, vy, vs) -> words``;
``player.fill(xbuf, ybuf, n) -> int`` writes n AD660 codes per axis (fewer = the DAC holds its last code).
"""

import struct
import time
from array import array
from collections import deque

import numpy as np

from protocol import can, core


class HoldPlayer:
    """A player that holds the P-FSM at fixed AD660 codes (0x8000 = 0 V)."""

    def __init__(self, x_code=0x8000, y_code=0x8000):
        self.x_code, self.y_code = x_code, y_code

    def fill(self, xbuf, ybuf, n):
        xbuf[:n] = array("H", [self.x_code]) * n
        ybuf[:n] = array("H", [self.y_code]) * n
        return n


class SinePlayer:
    """A player that drives both P-FSM axes with a sine (X) and a cosine (Y) of ``amp`` AD660 codes at ``hz``."""

    def __init__(self, amp=800, hz=2.0, pfsm_hz=10600.0):
        self.i, self.amp, self.w = 0, amp, 2 * np.pi * hz / pfsm_hz

    def fill(self, xbuf, ybuf, n):
        k = self.i + np.arange(n)
        xbuf[:n] = array("H", (0x8000 + np.round(self.amp * np.sin(self.w * k))).astype(np.uint16).tobytes())
        ybuf[:n] = array("H", (0x8000 + np.round(self.amp * np.cos(self.w * k))).astype(np.uint16).tobytes())
        self.i += n
        return n


class Lockstep:
    """Runs ``bench`` against ``controller`` and ``player`` (None = hold the P-FSM at 0 V).

    ``run(duration_s)`` returns a dict: ``q2`` (m x 5 int64: sample, t_us, vx, vy, vs), ``truth_arcsec``
    (m x 2, true sky error at the Q2 instants), ``counters``, ``config``, ``seed``, ``ticks``, ``wall_s``
    and the timing parameters. ``record=True`` adds ``q1`` (ticks x 3) and ``fsm_v`` (ticks x 2).
    ``on_q2(sample)`` is called with each Q2 sample as it falls (the tuple of ``Bench.step``), e.g. to forward
    Q2_SAMPLE packets to a recorder.
    """

    def __init__(self, bench, controller, player=None, rate_hz=637.8, pfsm_hz=10600.0, deadline_s=1.0,
                 realtime=False, block_ticks=256, record=False, on_q2=None):
        if not 100.0 <= pfsm_hz <= 1e6:
            raise ValueError("pfsm_hz = %r must be in [100, 1e6]" % pfsm_hz)
        if pfsm_hz < rate_hz:
            raise ValueError("the control rate %g Hz is above the P-FSM's update rate %g Hz (at least one P-FSM "
                             "code per tick)" % (rate_hz, pfsm_hz))
        if deadline_s <= 0:
            raise ValueError("deadline_s = %r must be > 0" % deadline_s)
        if block_ticks < 1:
            raise ValueError("block_ticks = %r must be >= 1" % block_ticks)
        self.bench = bench
        self.controller = controller
        self.player = player if player is not None else HoldPlayer()
        bench.set_rate(rate_hz)
        self.rate_hz = float(rate_hz)
        self.pfsm_hz = float(pfsm_hz)
        self.deadline_s = float(deadline_s)
        self.realtime = realtime
        self.block_ticks = int(block_ticks)
        self.record = record
        self.on_q2 = on_q2
        self.tick = 0
        self._bench_tick0 = bench.tick
        self.n_overrun = 0
        self.n_player_short = 0
        self._last_x = 0x8000
        self._last_y = 0x8000

    def _counts(self, k0, n):
        """P-FSM updates falling in ticks k0 .. k0+n-1 on the uniform pfsm_hz clock (>= 1 per tick)."""
        r = self.pfsm_hz / self.rate_hz
        edges = np.floor(np.arange(k0, k0 + n + 1) * r).astype(np.int64)
        return np.maximum(np.diff(edges), 1)

    def _load_block(self, k0, n):
        counts = self._counts(k0, n)
        total = int(counts.sum())
        xbuf = array("H", bytes(2 * total))
        ybuf = array("H", bytes(2 * total))
        got = self.player.fill(xbuf, ybuf, total)
        got = total if got is None else max(0, min(int(got), total))
        if got < total:
            self.n_player_short += 1
            xa = np.frombuffer(xbuf, dtype=np.uint16).copy()
            ya = np.frombuffer(ybuf, dtype=np.uint16).copy()
            xa[got:] = xa[got - 1] if got else self._last_x
            ya[got:] = ya[got - 1] if got else self._last_y
        else:
            xa = np.frombuffer(xbuf, dtype=np.uint16)
            ya = np.frombuffer(ybuf, dtype=np.uint16)
        self._last_x, self._last_y = int(xa[-1]), int(ya[-1])
        self.bench.load_pfsm(xa, ya, counts)

    def run(self, duration_s=None, n_ticks=None, progress=None):
        """Run for ``duration_s`` of virtual time (or ``n_ticks`` ticks); may be called again to continue."""
        if n_ticks is None:
            if duration_s is None or duration_s < 0:
                raise ValueError("run: give duration_s >= 0 or n_ticks")
            n_ticks = int(round(duration_s * self.rate_hz))
        bench, ctrl = self.bench, self.controller
        on_tick = ctrl.on_tick
        rate = self.rate_hz
        us_per_tick = 1e6 / rate
        q2_rows, q1_rows, fsm_rows = [], [], []
        on_q2 = self.on_q2
        realtime, record = self.realtime, self.record
        clock = time.perf_counter
        t_wall0 = clock()
        t_rt0 = t_wall0 - self.tick / rate
        missed0 = bench.n_missed
        k = self.tick - 1
        end = self.tick + n_ticks
        self.partial = None
        try:
            while k + 1 < end:
                n = min(self.block_ticks, end - k - 1)
                self._load_block(k + 1, n)
                if realtime or on_q2 is not None:
                    k = self._ticks_general(k + 1, n, t_rt0, q2_rows, q1_rows, fsm_rows)
                else:       # virtual time, Q2 samples taken after the block: the bench's loop
                    bench.run_ticks(n, q2_rows, on_tick, k + 1, us_per_tick, q1_rows if record else None,
                                    fsm_rows)
                    k += n
                if progress is not None:
                    progress(k + 1)
        except BaseException:
            # interrupted or failed mid-call: keep every sample already taken (``partial``), then re-raise
            self.tick = bench.tick - self._bench_tick0
            self.n_overrun += bench.n_missed - missed0
            missed0 = bench.n_missed
            self.partial = self._result(q2_rows, q1_rows, fsm_rows, self.tick - (end - n_ticks), clock() - t_wall0)
            raise
        finally:
            self.tick = bench.tick - self._bench_tick0
            self.n_overrun += bench.n_missed - missed0
        return self._result(q2_rows, q1_rows, fsm_rows, n_ticks, clock() - t_wall0)

    def _result(self, q2_rows, q1_rows, fsm_rows, n_ticks, wall):
        bench, rate, realtime = self.bench, self.rate_hz, self.realtime
        rows = np.array(q2_rows, dtype=float).reshape(-1, 7)
        out = {"q2": rows[:, :5].astype(np.int64), "truth_arcsec": rows[:, 5:7],
               "counters": self.counters(), "config": bench.config, "seed": bench.seed, "ticks": n_ticks,
               "wall_s": wall, "rate_hz": rate, "pfsm_hz": self.pfsm_hz, "realtime": realtime,
               "realtime_factor": (n_ticks / rate) / wall if wall > 0 else float("inf")}
        if self.record:
            out["q1"] = np.array(q1_rows, dtype=np.int64).reshape(-1, 3)
            out["fsm_v"] = np.array(fsm_rows, dtype=float).reshape(-1, 2)
        return out

    def _ticks_general(self, k0, n, t_rt0, q2_rows, q1_rows, fsm_rows):
        """Ticks k0 .. k0+n-1 one by one: the real-time pacing and deadline, ``on_q2`` as each sample falls."""
        bench, ctrl = self.bench, self.controller
        rate, deadline, realtime, on_q2 = self.rate_hz, self.deadline_s, self.realtime, self.on_q2
        us_per_tick = 1e6 / rate
        clock = time.perf_counter
        if bench.tab.timed:     # the board's timing lives in the bench's loop: one tick per call
            return self._ticks_timed(k0, n, t_rt0, q2_rows, q1_rows, fsm_rows)
        for k in range(k0, k0 + n):
            if realtime:
                self._pace(k, t_rt0)
            vx, vy, vs = bench.q1_sample()
            words = ctrl.on_tick(k, int(k * us_per_tick + 0.5), vx, vy, vs)
            if realtime and clock() > t_rt0 + k / rate + deadline:
                words = None
            if words:
                bench.spi_words(words)
            else:
                self.n_overrun += 1
            q2 = bench.step()
            if q2:
                q2_rows.extend(q2)
                if on_q2 is not None:
                    for sample in q2:
                        on_q2(sample)
            if self.record:
                q1_rows.append((vx, vy, vs))
                fsm_rows.append(bench.fsm_v)
        return k

    def _pace(self, k, t_rt0):
        """Real time: wait for tick k's wall-clock instant; a remote controller gets the time left to the deadline."""
        due = t_rt0 + k / self.rate_hz
        now = time.perf_counter()
        if now < due:
            time.sleep(due - now)
        if hasattr(self.controller, "timeout_s"):
            self.controller.timeout_s = max(0.0, due + self.deadline_s - time.perf_counter())

    def _ticks_timed(self, k0, n, t_rt0, q2_rows, q1_rows, fsm_rows):
        """``_ticks_general`` for a bench with the board's timing: each tick through ``Bench.run_ticks`` (the
        controller wrapped for the real-time pacing and deadline); overruns are counted by the bench."""
        bench, ctrl = self.bench, self.controller
        rate, deadline, realtime, on_q2 = self.rate_hz, self.deadline_s, self.realtime, self.on_q2
        clock = time.perf_counter

        def on_tick(k, t_us, vx, vy, vs):
            if realtime:
                self._pace(k, t_rt0)
            words = ctrl.on_tick(k, t_us, vx, vy, vs)
            if realtime and clock() > t_rt0 + k / rate + deadline:
                return None
            return words

        rec = q1_rows if self.record else None
        for k in range(k0, k0 + n):
            m = len(q2_rows)
            bench.run_ticks(1, q2_rows, on_tick, k, 1e6 / rate, rec, fsm_rows)
            if on_q2 is not None:
                for sample in q2_rows[m:]:
                    on_q2(sample)
        return k0 + n - 1

    def counters(self):
        c = dict(self.bench.counters())
        c.update({"overruns": self.n_overrun, "player_short_blocks": self.n_player_short})
        if hasattr(self.controller, "counters"):
            c.update(("controller_" + k, v) for k, v in self.controller.counters().items())
        return c


class LinkFailure(OSError):
    """The link to the controller is dead or too noisy to keep lockstep: the run cannot go on correctly."""


class RemoteController:
    """Controller adapter over a protocol Link (docs/INTERFACES.md): sends TICK, waits for the one FSM_SPI
    (up to 4 words) that answers it, and resends the same TICK when the answer does not come.

    Exactly once: the controller steps on the first copy of TICK k and answers any resend of k from its cache
    (``firmware.hal.link``), so a resend costs time, never a second integration.

    - ``try_timeout_s``: wait for an answer before the first resend, doubled at each resend up to
      ``MAX_TRY_S`` (a slow peer is not flooded); ``tries`` sends at most. None: one try of ``timeout_s``.
      A frame that arrives damaged while the answer is awaited (``protocol.can.rx_damaged``: a failed check, an
      ISO-TP frame breaking its rules, a malformed Lawicel line) triggers the resend at once (``resent_early``);
      slowness does not: a transfer timed out on receive, and the link's own send timeouts, wait for the try;
    - ``timeout_s``: a bound on the whole wait for one tick; after the tries or this the tick is an overrun
      (the mirror holds its last input, as hardware would). Real-time mode sets it per tick from the deadline;
    - an overrun while the link kept delivering damaged frames means the link is too noisy to keep lockstep:
      ``LinkFailure``. An overrun on a link that delivered no damage is an outage: the clock goes on,
      each further tick gets one try until the link answers, and ``max_failed_ticks`` consecutive overruns
      end the run (``LinkFailure``); None: no bound;
    - ``status_decim``: when set, CTRL_STATUS is due on ticks k with k % status_decim == 0 and is part of the
      answer: a resend asks for it again. Duplicate or older CTRL_STATUS are dropped.

    FSM_SPI answering an older tick arrives late: counted and dropped. Every other packet received meanwhile
    goes to ``inbox`` (a deque of (pid, src, dst, seq, payload)) for the ground.
    """

    MAX_TRY_S = 0.1
    SLICE_S = 0.0005      # after this without the answer, a damaged frame seen meanwhile triggers the resend

    def __init__(self, link, dst="CONTROLLER", timeout_s=1.0, try_timeout_s=None, tries=1,
                 max_failed_ticks=None):
        self.link = link
        self.tries = tries
        self.dst = core.NODE[dst] if isinstance(dst, str) else dst
        self.timeout_s = timeout_s
        self.try_timeout_s = try_timeout_s
        self.max_failed_ticks = max_failed_ticks
        self.status_decim = None
        self.inbox = deque()
        self.n_late = 0
        self.n_timeout = 0
        self.n_bad = 0
        self.n_resent = 0
        self.n_early = 0
        self.n_rx = 0                # packets taken from the link
        self.tick_now = 0            # the tick being answered (a per-tick clock for fault injection)
        self.n_status_dup = 0
        self.n_status_missed = 0
        self.failed_run = 0          # consecutive overruns
        self.last_status_tick = -1
        self._tick_id = core.PACKET_ID["TICK"]
        self._spi_id = core.PACKET_ID["FSM_SPI"]
        self._status_id = core.PACKET_ID["CTRL_STATUS"]
        self._status_tick = core.PACKET[self._status_id].names.index("tick")
        self._tick_fmt = struct.Struct(core.PACKET[self._tick_id].fmt)   # ADC counts are already in range
        self._pending = deque()
        self.hello_tries = 0

    def wait_peer(self, timeout_s):
        """HELLO to the peer until its first packet (its HELLO: it says one when its link opens, and answers
        each of ours) arrives; True if one did. A HELLO lost either way costs a retry (``protocol.link.
        first_contact``: 50 ms, doubling up to 0.5 s); ``hello_tries`` counts them.

        Start the clock after it: a TICK written before the peer opened a pty may be flushed by its raw-mode
        setup (a HELLO so flushed is sent again)."""
        from protocol.link import first_contact
        hello = core.PACKET_ID["HELLO"]
        payload = core.encode_payload(hello, node=self.link.node)

        def check():
            if self.link.closed:
                raise OSError("the link closed before the controller spoke")
        try:
            self.hello_tries, got = first_contact(
                lambda: self.link.send_raw(hello, self.link.node, self.dst, payload),
                lambda t: self.link.recv(timeout=t), timeout_s, 0.05, 0.5, check)
        except OSError:
            return False
        self._pending.extend(got or ())
        return got is not None

    def poll(self, timeout_s):
        """Take what the link delivers within ``timeout_s`` into ``inbox`` (between ticks: commands)."""
        self._pending.extend(self.link.recv(timeout=timeout_s))
        self._sort(-1)

    def _sort(self, tick):
        """Move pending packets to ``inbox``; the FSM_SPI words for ``tick`` (or None) and whether its status
        came."""
        pending, inbox = self._pending, self.inbox
        words = None
        got_status = False
        while pending:
            pkt = pending.popleft()
            self.n_rx += 1
            pid = pkt[0]
            if pid == self._spi_id or pid == self._status_id:
                try:
                    vals = core.decode_payload(pid, pkt[4])
                except (ValueError, struct.error):       # a payload of the wrong length
                    self.n_bad += 1
                    continue
            if pid == self._spi_id:
                if vals[0] != tick or words is not None:
                    self.n_late += 1
                    continue
                words = list(vals[2:2 + vals[1]])
            elif pid == self._status_id:
                st = vals[self._status_tick]
                if st <= self.last_status_tick:
                    self.n_status_dup += 1
                    continue
                self.last_status_tick = st
                if st == tick:
                    got_status = True
                inbox.append(pkt)
            else:
                inbox.append(pkt)
        return words, got_status

    def _damaged(self):
        """Frames the link has received damaged so far (``protocol.can.rx_damaged``; 0 without counters)."""
        try:
            c = self.link.counters()
        except AttributeError:
            return 0
        return can.rx_damaged(c)

    def on_tick(self, tick, t_us, vx, vy, vs):
        link = self.link
        tick &= 0xFFFFFFFF
        self.tick_now = tick
        payload = self._tick_fmt.pack(tick, t_us & 0xFFFFFFFF, vx, vy, vs)
        decim = self.status_decim
        want_status = bool(decim) and tick % decim == 0 and tick > self.last_status_tick
        clock = time.perf_counter
        t0 = clock()
        try_s = self.try_timeout_s or self.timeout_s
        tries_left = self.tries if self.try_timeout_s else 1
        end = t0 + self.timeout_s
        if self.failed_run:               # the link was out on the last tick: one try until it answers
            tries_left = 1
        words, got_status = None, False
        tries = 0
        damaged0 = None
        rx0 = self.n_rx
        while True:
            if tries == 1:
                damaged0 = self._damaged()
            if tries:
                self.n_resent += 1
            link.send_raw(self._tick_id, link.node, self.dst, payload)
            tries += 1
            tries_left -= 1
            try_end = min(end, clock() + try_s)
            try_s = min(2 * try_s, self.MAX_TRY_S)     # back off: a slow peer is not flooded with resends
            seen = self._damaged()
            while True:
                w, s = self._sort(tick)
                if w is not None:
                    words = w
                got_status = got_status or s
                if words is not None and (got_status or not want_status):
                    self.failed_run = 0
                    return words
                left = try_end - clock()
                if left <= 0 or link.closed:
                    # out of time: still take what has arrived (a late answer), so the peer's replies never
                    # back up on the link while the bench runs behind the wall clock (real-time mode)
                    self._pending.extend(link.recv(timeout=0))
                    self._sort(-1)
                    break
                self._pending.extend(link.recv(timeout=min(left, self.SLICE_S)))
                if not self._pending and self._damaged() != seen:
                    self.n_early += 1     # a damaged frame came instead of the answer: resend now
                    break
            if link.closed or clock() >= end or tries_left <= 0:
                break
        if words is not None:             # the command came, its telemetry did not: apply the command
            self.n_status_missed += 1
            self.failed_run = 0
            return words
        self.n_timeout += 1
        self._sort(-1)
        # consecutive overruns on a link that delivered nothing meanwhile: a late answer means slow, not down
        self.failed_run = 1 if self.n_rx != rx0 else self.failed_run + 1
        if link.closed:
            why = getattr(link, "closed_why", None)
            raise LinkFailure("the controller's link closed at tick %d%s" % (tick, ": " + why if why else ""))
        if damaged0 is not None and self._damaged() != damaged0 and words is None and tries > 1:
            raise LinkFailure("tick %d unanswered after %d tries in %.0f ms while the link kept delivering "
                              "damaged frames: too noisy to keep lockstep" % (tick, tries,
                                                                              (clock() - t0) * 1e3))
        if self.max_failed_ticks and self.failed_run >= self.max_failed_ticks:
            raise LinkFailure("no answer for %d consecutive ticks (from tick %d): the link is down"
                              % (self.failed_run, tick - self.failed_run + 1))
        return None

    def counters(self):
        return {"late": self.n_late, "timeouts": self.n_timeout, "bad": self.n_bad, "resent": self.n_resent, "resent_early": self.n_early,
                "status_dup": self.n_status_dup, "status_missed": self.n_status_missed}
