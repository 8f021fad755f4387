"""The hardware commands: touchloc hand-info and touchloc emulate."""

from touchloc.cli import main
from touchloc.hardware.emulator import DSACON32mEmulator, SDH2Emulator, SimHand, TCPServer


def test_hand_info_against_emulators(capsys):
    sim = SimHand()
    with TCPServer(SDH2Emulator(sim)) as hs, TCPServer(DSACON32mEmulator(sim)) as ts:
        code = main(["hand-info", "--port", hs.url, "--tactile-port", ts.url])
    out = capsys.readouterr().out
    assert code == 0
    assert "SDH-2 firmware 0.0.2.15" in out and "7 axes" in out
    assert "matrix 5: 6 x 13 texels" in out


def test_hand_info_needs_an_address(capsys):
    assert main(["hand-info"]) == 1
    assert "--port" in capsys.readouterr().err


def test_emulate_prints_addresses_and_stops(capsys):
    assert main(["emulate", "--hand", "tcp", "--tactile", "pty", "--duration", "0.3"]) == 0
    out = capsys.readouterr().out
    assert "SDH-2 emulator on socket://127.0.0.1:" in out
    assert "DSACON32m emulator on /dev/" in out
