"""Adversarial review of the fine-pointing half: each test failed on the code before its fix."""

from collections import deque

from firmware.controller import CALIBRATE, HOLD, Controller
from ground.rig import P_ACK, InprocController, Rig
from protocol import core


class _LateAckEndpoint(InprocController):
    """An in-process controller behind a link that is slow once and lossy once: the first command's ACK arrives
    only after the rig resent it (so two ACKs for it come back), and the next command's first frame is lost."""

    def __init__(self, ctrl):
        InprocController.__init__(self, ctrl)
        self.n_sent = 0
        self.held = deque()

    def send_ground(self, pid, payload, seq, dst=None):
        self.n_sent += 1
        if self.n_sent == 3:          # the second command's first copy: lost on the link
            return seq
        before = len(self.inbox)
        InprocController.send_ground(self, pid, payload, seq)
        if self.n_sent == 1:          # the first copy's ACK is late: it arrives after the resend
            while len(self.inbox) > before:
                self.held.append(self.inbox.pop())
        elif self.held:
            self.inbox.extend(self.held)
            self.held.clear()
        return seq


def test_a_late_duplicate_ack_is_not_taken_for_the_next_command():
    """Rig.command matched replies by packet id only: the second ACK of a resent CTRL_SETTINGS(CALIBRATE) was taken
    for the next CTRL_SETTINGS(HOLD) whose frame was lost, so the ground went on with the controller not in HOLD."""
    ctrl = Controller()
    rig = Rig(_LateAckEndpoint(ctrl))
    rig.cmd_timeout_s = 0.001
    rig.settings("CALIBRATE")         # ACK late: resent, both copies ACKed
    assert ctrl.mode == CALIBRATE and rig.n_cmd_retries == 1
    rig.settings("HOLD")              # first copy lost
    assert ctrl.mode == HOLD
    assert rig.n_cmd_retries == 2
    assert not [p for p in rig.replies if p[0] == P_ACK and p[4][0] == core.PACKET_ID["CTRL_SETTINGS"]]


def test_calibrate_refuses_a_bad_dv_as_bad_input(tmp_path, capsys):
    """--dv nan/0/-1/10 was refused only once the rig (and, for micropython, its process) ran, as a failed run
    (exit 1, "calibration stopped"); the README and --help promise exit 2 for bad input."""
    from ground.cli import main as fps
    for v in ("nan", "0", "-1", "10"):
        rc = fps(["calibrate", "-o", str(tmp_path / "cal.json"), "--grid", "2", "--dv", v, "--no-plots"])
        err = capsys.readouterr().err
        assert rc == 2 and "--dv" in err and "calibration stopped" not in err, (v, rc, err)
    assert not list(tmp_path.iterdir())
