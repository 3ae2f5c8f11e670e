"""SLAM-ready output: DSO's times.txt and TUM's rgb.txt carry the frames' source timestamps, the camera file is
copied as it is after a size check, and the rescale keeps every pixel's ray (DSO's and COLMAP's conventions)."""

from __future__ import annotations

import json
from fractions import Fraction
from pathlib import Path

import cv2
import pytest
from colonlight_cli.main import app
from typer.testing import CliRunner

from colonlight.errors import InputError
from colonlight.slam_layout import camera_for_frames, parse_camera, rescale_camera

from ...media import make_clip, make_vfr_clip, needs_ffmpeg, read_index, vfr_times

runner = CliRunner()

DSO_PINHOLE = "Pinhole 100.5 101.5 63.5 47.5 0\n128 96\nnone\n128 96\n"
COLMAP_TWO = (
    "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
    "1 OPENCV 640 480 500 510 320.5 240.25 0.1 -0.05 0.001 0.002\n2 SIMPLE_RADIAL 640 480 480 319 241 0.02\n"
)


def invoke(*args: object) -> tuple[int, str]:
    result = runner.invoke(app, [str(a) for a in args])
    return result.exit_code, result.output


def _times(path: Path) -> list[tuple[str, float]]:
    return [(line.split()[0], float(line.split()[1])) for line in path.read_text().splitlines()]


def _tum(path: Path) -> list[tuple[float, str]]:
    """rgb.txt read as ORB-SLAM3's mono_tum does: three lines skipped, then 'time path' per line."""
    lines = path.read_text().splitlines()
    assert all(line.startswith("#") for line in lines[:3])
    return [(float(line.split()[0]), line.split()[1]) for line in lines[3:]]


def test_variable_frame_rate_clip_keeps_its_own_timestamps(tmp_path: Path, random_weights: Path) -> None:
    make_vfr_clip(tmp_path / "v" / "vfr.mp4", vfr_times(30))  # in a 1/1000 s time base
    times = [round(t / Fraction(1, 1000)) / 1000 for t in vfr_times(30)]
    code, out = invoke(
        "enhance", tmp_path / "v" / "vfr.mp4", "-o", tmp_path / "o", "--fps", "0", "--weights", random_weights, "-q"
    )
    assert code == 0, out
    clip = tmp_path / "o" / "vfr"
    dso = _times(clip / "times.txt")
    assert [i for i, _ in dso] == [f"{k:06d}" for k in range(30)]
    assert [t for _, t in dso] == pytest.approx(times, abs=1e-6)  # the source's presentation times, not k / fps
    tum = _tum(clip / "rgb.txt")
    assert [t for t, _ in tum] == pytest.approx(times, abs=1e-6)
    assert [p for _, p in tum] == [f"frames/{k:06d}.png" for k in range(30)]
    assert all((clip / p).is_file() for _, p in tum)
    assert not (clip / "camera.txt").exists() and not (clip / "cameras.txt").exists()


@needs_ffmpeg
def test_resampled_clip_lists_each_frame_at_its_source_time_and_copies_the_camera(tmp_path: Path) -> None:
    make_clip(tmp_path / "c25.mp4", n_frames=50, fps=25)  # 128x96
    cam = tmp_path / "calib" / "camera.txt"
    cam.parent.mkdir()
    cam.write_text(DSO_PINHOLE)
    code, out = invoke(
        "enhance",
        tmp_path / "c25.mp4",
        "-o",
        tmp_path / "o",
        "--method",
        "none",
        "--camera",
        cam,
        "-q",
        "--format",
        "png",
    )
    assert code == 0, out
    clip = tmp_path / "o" / "c25"
    dso, tum = _times(clip / "times.txt"), _tum(clip / "rgb.txt")
    assert len(dso) == len(tum) == len(list((clip / "frames").glob("*.png"))) == 36  # 2 s at 18 fps
    for (index, t_dso), (t_tum, rel) in zip(dso, tum, strict=True):
        source_index = read_index(cv2.cvtColor(cv2.imread(str(clip / rel)), cv2.COLOR_BGR2RGB))
        assert rel == f"frames/{index}.png"
        assert t_dso == t_tum == pytest.approx(source_index / 25, abs=1e-6)  # which source frame it is, and its time
    assert (clip / "camera.txt").read_bytes() == cam.read_bytes()  # enhance never resizes: copied as it is
    gammas = json.loads((clip / "gammas.json").read_text())
    assert [f["source_time_s"] for f in gammas["frames"]] == [t for _, t in dso]

    # Another camera redoes the clip (it is part of its settings); no camera removes the copy.
    colmap = tmp_path / "calib" / "cameras.txt"
    colmap.write_text("1 PINHOLE 128 96 100 100 64 48\n")
    assert (
        invoke("enhance", tmp_path / "c25.mp4", "-o", tmp_path / "o", "--method", "none", "--camera", colmap, "-q")[0]
        == 0
    )
    assert (clip / "cameras.txt").read_bytes() == colmap.read_bytes() and not (clip / "camera.txt").exists()
    assert invoke("enhance", tmp_path / "c25.mp4", "-o", tmp_path / "o", "--method", "none", "-q")[0] == 0
    assert not (clip / "cameras.txt").exists() and (clip / "times.txt").is_file()


def test_video_only_output_has_times_but_no_rgb_list(tmp_path: Path, random_weights: Path) -> None:
    make_vfr_clip(tmp_path / "a.mp4", [0.0, 0.05, 0.1, 0.2])
    code, out = invoke(
        "enhance",
        tmp_path / "a.mp4",
        "-o",
        tmp_path / "o",
        "--no-frames",
        "--video",
        "--fps",
        "0",
        "--weights",
        random_weights,
        "-q",
    )
    assert code == 0, out
    assert [t for _, t in _times(tmp_path / "o" / "a" / "times.txt")] == pytest.approx([0.0, 0.05, 0.1, 0.2])
    assert not (tmp_path / "o" / "a" / "rgb.txt").exists()


def test_camera_for_another_size_fails_that_clip_before_anything_is_written(
    tmp_path: Path, random_weights: Path
) -> None:
    make_vfr_clip(tmp_path / "in" / "small.mp4", vfr_times(6))  # 128x96
    make_vfr_clip(tmp_path / "in" / "big.mp4", vfr_times(6), size=(160, 120))
    cam = tmp_path / "camera.txt"
    cam.write_text(DSO_PINHOLE)
    code, out = invoke(
        "enhance",
        tmp_path / "in",
        "-o",
        tmp_path / "o",
        "--fps",
        "0",
        "--camera",
        cam,
        "--weights",
        random_weights,
        "-q",
    )
    assert code == 1
    assert "calibrated for 128x96 images, but this clip's frames are 160x120" in out and "Traceback" not in out
    (line,) = [ln for ln in out.splitlines() if "calibrated for" in ln]
    assert "big" in line.split("calibrated for")[0], line  # the clip is named, not only the camera file
    assert not (tmp_path / "o" / "big" / "frames").exists() and not (tmp_path / "o" / "big" / "gammas.json").exists()
    assert (tmp_path / "o" / "small" / "camera.txt").read_text() == DSO_PINHOLE  # the other clip completes


def test_malformed_or_missing_camera_file_is_a_usage_error(tmp_path: Path) -> None:
    make_vfr_clip(tmp_path / "a.mp4", vfr_times(4))
    bad = tmp_path / "bad.txt"
    bad.write_text("Pinhole 1 2 3\n128 96\nnone\n128 96\n")
    code, out = invoke("enhance", tmp_path / "a.mp4", "-o", tmp_path / "o", "--camera", bad, "-m", "none")
    assert code == 2 and str(bad) in out and "Pinhole takes 5 parameters" in out and "Traceback" not in out
    code, out = invoke(
        "enhance", tmp_path / "a.mp4", "-o", tmp_path / "o", "--camera", tmp_path / "nope.txt", "-m", "none"
    )
    assert code == 2 and "nope.txt" in out and "cannot read the camera file" in out
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").rglob("*.png"))


def test_a_camera_file_with_a_byte_order_mark_is_refused_saying_so() -> None:
    """DSO and COLMAP read the mark as part of the first token; judged as DSO, the file failed as a malformed one."""
    for text in (DSO_PINHOLE, COLMAP_TWO):
        with pytest.raises(InputError, match=r"cam.txt: starts with a byte-order mark \(U\+FEFF\)"):
            parse_camera("\ufeff" + text, "cam.txt")
        assert parse_camera(text, "cam.txt").sizes  # the same file without it is taken


def test_camera_files_are_split_as_dso_and_colmap_split_them() -> None:
    """Lines at "\\n" only and tokens at C's blanks: Python's splitlines() and split() also break at U+2028, NEL,
    no-break spaces and form feeds, so a file those tools misread (one line, one token) was accepted."""
    crlf = DSO_PINHOLE.replace("\n", "\r\n")
    assert parse_camera(crlf, "c.txt").sizes == parse_camera(DSO_PINHOLE, "c.txt").sizes == ((128, 96),)
    assert parse_camera(COLMAP_TWO.replace("\n", "\r\n"), "c.txt").sizes == ((640, 480), (640, 480))
    assert parse_camera(DSO_PINHOLE.replace(" ", "\t"), "c.txt").sizes == ((128, 96),)  # tabs are blanks in C too
    for bad in (
        DSO_PINHOLE.replace("\n", "\u2028"),  # one line to DSO
        DSO_PINHOLE.replace("\n", "\x0c"),
        DSO_PINHOLE.replace("128 96", "128\u00a096"),  # one token to sscanf
        COLMAP_TWO.replace("640 480", "640\u2003480"),
    ):
        with pytest.raises(InputError, match="c.txt: not a valid"):
            parse_camera(bad, "c.txt")


# --------------------------------------------------------------------------------------------------- rescale


def _project(fx: float, fy: float, cx: float, cy: float, x: float = 0.3, y: float = -0.2) -> tuple[float, float]:
    return fx * x + cx, fy * y + cy


@pytest.mark.parametrize("prefix", ["Pinhole ", ""])
def test_dso_rescale_keeps_each_ray_at_the_same_place_in_the_image(prefix: str) -> None:
    cam = parse_camera(f"{prefix}400 410 319.5 239.5 0\n640 480\nnone\n640 480\n", "cam.txt")
    lines = rescale_camera(cam, (320, 240)).splitlines()
    tokens = lines[0].split()
    assert tokens[0] == "Pinhole" if prefix else len(tokens) == 5
    fx, fy, cx, cy, zero = (float(t) for t in tokens[-5:])
    assert (fx, fy, zero) == (200, 205, 0) and (cx, cy) == (159.5, 119.5)  # the image centre stays the centre
    u, v = _project(400, 410, 319.5, 239.5)
    u2, v2 = _project(fx, fy, cx, cy)
    assert (u2 + 0.5, v2 + 0.5) == pytest.approx(((u + 0.5) / 2, (v + 0.5) / 2))  # DSO: pixel centres at integers
    assert lines[1:] == ["320 240", "none", "320 240"]  # 'none' needs the output size equal to the input's


def test_dso_relative_radtan_and_fov_keep_their_parameters() -> None:
    radtan = parse_camera("0.5 0.6 0.49 0.51 -0.2 0.05 0.001 0.0\n640 480\ncrop\n512 384\n", "r.txt")
    assert rescale_camera(radtan, (1280, 960)).splitlines() == [
        "0.5 0.6 0.49 0.51 -0.2 0.05 0.001 0",
        "1280 960",
        "crop",
        "1024 768",
    ]
    fov = parse_camera("FOV 300 300 319.5 239.5 0.9\n640 480\n0.5 0.6 0.5 0.5 0\n640 480\n", "f.txt")
    first, *rest = rescale_camera(fov, (320, 240)).splitlines()
    assert first == "FOV 150 150 159.5 119.5 0.9" and rest == ["320 240", "0.5 0.6 0.5 0.5 0", "320 240"]


def test_colmap_rescale_scales_focal_and_principal_point_and_keeps_comments() -> None:
    cam = parse_camera(COLMAP_TWO, "cameras.txt")
    assert cam.kind == "colmap" and cam.sizes == ((640, 480), (640, 480))
    lines = rescale_camera(cam, (320, 240)).splitlines()
    assert lines[:2] == COLMAP_TWO.splitlines()[:2]
    assert lines[2] == "1 OPENCV 320 240 250 255 160.25 120.125 0.1 -0.05 0.001 0.002"  # COLMAP: centres at +0.5
    assert lines[3] == "2 SIMPLE_RADIAL 320 240 240 159.5 120.5 0.02"
    with pytest.raises(InputError, match="changes the aspect ratio"):
        rescale_camera(cam, (320, 480))


def test_camera_for_frames_copies_as_is_or_rescales_from_the_source_size() -> None:
    cam = parse_camera(COLMAP_TWO, "cameras.txt")
    assert camera_for_frames(cam, (640, 480)) == COLMAP_TWO
    assert camera_for_frames(cam, (320, 240), source_size=(640, 480)) == rescale_camera(cam, (320, 240))
    with pytest.raises(
        InputError, match=r"cameras.txt: calibrated for 640x480 images, but this clip's frames are 128x96"
    ):
        camera_for_frames(cam, (128, 96))
    with pytest.raises(InputError, match="not a valid COLMAP"):
        parse_camera("1 PINHOLE 640 480 500 500 320\n", "c.txt")
    with pytest.raises(InputError, match="not a valid DSO"):
        parse_camera("Pinhole 1 1 1 1 0\n640 480\n", "d.txt")


@pytest.mark.parametrize(
    "line",
    [
        "1 OPENCV 640 480 500 510 320.5 240.25 0.1 -0.05 0.001 0.002",
        "1 SIMPLE_RADIAL 640 480 480 319 241 0.02",
        "1 PINHOLE 1350 1080 900 905 674.5 539.5",
        "1 OPENCV_FISHEYE 1350 1080 600 601 676 541 0.1 0.01 -0.002 0.0003",
    ],
)
def test_colmap_rescale_agrees_with_colmaps_own(line: str) -> None:
    pycolmap = pytest.importorskip("pycolmap", reason="pycolmap (the eval extra) is not installed")
    _, model, w, h, *params = line.split()
    to = (int(w) * 2 // 3, int(h) * 2 // 3)
    ours = rescale_camera(parse_camera(line + "\n", "cameras.txt"), to).split()
    theirs = pycolmap.Camera(model=model, width=int(w), height=int(h), params=[float(p) for p in params])
    theirs.rescale(*to)
    assert ours[1:4] == [model, str(to[0]), str(to[1])]
    assert [float(p) for p in ours[4:]] == pytest.approx(list(theirs.params), rel=1e-9)
