"""The encode / decode / demo verbs end to end through the CLI entry point."""

from __future__ import annotations

import numpy as np

from fbaconf.bitstreams.faptext import read_fap_file, write_fap
from fbaconf.bitstreams.frames import FapFrames, first_difference
from fbaconf.bitstreams.synth import synthetic_sequence
from fbaconf.cli import main


def test_encode_decode_round_trip_through_cli(tmp_path, capsys):
    src = synthetic_sequence(30, 25.0)
    (tmp_path / "in.fap").write_text(write_fap(src))
    assert (
        main(
            [
                "encode",
                str(tmp_path / "in.fap"),
                "-o",
                str(tmp_path / "s.fba"),
                "--quant",
                "2",
                "--intra-every",
                "10",
                "--recon",
                str(tmp_path / "recon.npz"),
            ]
        )
        == 0
    )
    assert main(["decode", str(tmp_path / "s.fba"), "-o", str(tmp_path / "out.npz")]) == 0
    assert main(["decode", str(tmp_path / "s.fba"), "-o", str(tmp_path / "out.fap")]) == 0
    recon = FapFrames.load_npz(tmp_path / "recon.npz")
    got = FapFrames.load_npz(tmp_path / "out.npz")
    assert first_difference(recon, got) is None
    text_frames, _, warnings = read_fap_file(tmp_path / "out.fap")
    assert not warnings
    np.testing.assert_array_equal(text_frames.values[:, 2:], got.values[:, 2:])
    assert "encoded 30 frames" in capsys.readouterr().out


def test_bad_input_exits_2_without_output(tmp_path, capsys):
    (tmp_path / "bad.fba").write_bytes(b"\x00\x00\x01\xba\xff\xff")
    assert main(["decode", str(tmp_path / "bad.fba"), "-o", str(tmp_path / "out.npz")]) == 2
    err = capsys.readouterr().err
    assert "bad.fba" in err and "bit offset" in err and "[rule " in err and "Traceback" not in err
    assert not (tmp_path / "out.npz").exists()
    assert list(tmp_path.iterdir()) == [tmp_path / "bad.fba"]  # no temp file left behind


def test_lossless_refusal_names_fap_frame_value(tmp_path, capsys):
    f = synthetic_sequence(3, 25.0, faps=[48], visemes=False, expressions=False)
    f.values[:, 47] = [10, 20, 5000]
    (tmp_path / "in.fap").write_text(write_fap(f))
    assert main(["encode", str(tmp_path / "in.fap"), "-o", str(tmp_path / "o.fba"), "--quant", "0"]) == 2
    err = capsys.readouterr().err
    assert "FAP 48" in err and "frame 2" in err and "5000" in err
    assert not (tmp_path / "o.fba").exists()


def test_demo(tmp_path, capsys):
    assert main(["demo", "-o", str(tmp_path / "d")]) == 0
    out = capsys.readouterr().out
    assert "result: OK" in out and (tmp_path / "d" / "demo_q1.fba").exists()
