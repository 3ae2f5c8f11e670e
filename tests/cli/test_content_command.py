"""`colonlight content` writes the content area `colonlight enhance` uses as a mask a host can be given, and the
mask reads back as that area; bad names, clips and masks fail in one line, with nothing written."""

from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from cli.main import app
from colonlight import InputError, OptionError, create_method, read_content_mask
from colonlight.content import ContentArea, ContentStream
from colonlight.content_mask import OVERLAY, SCENE, area_image
from colonlight.errors import FrameShapeError

runner = CliRunner()


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A synthetic H.264 clip behind a round border with on-screen text (`colonlight synth`)."""
    out = tmp_path_factory.mktemp("syn")
    args = ["synth", str(out), "--frames", "24", "--width", "192", "--height", "144", "--border", "round", "--text"]
    result = runner.invoke(app, [*args, "--fov", "0.9", "--seed", "3", "-j", "1"])
    assert result.exit_code == 0, result.output
    return out / "clip_00000" / "clip.mp4"


def test_the_mask_is_the_area_enhance_uses(clip: Path, tmp_path: Path) -> None:
    written = runner.invoke(app, ["content", str(clip), "-o", str(tmp_path / "mask.pgm")])
    assert written.exit_code == 0, written.output
    assert (tmp_path / "mask.pgm").read_bytes().startswith(b"P5\n192 144\n255\n")
    area = read_content_mask(tmp_path / "mask.pgm")
    assert area.overlay.any() and not area.fov.all()
    enhanced = runner.invoke(app, ["enhance", str(clip), "-o", str(tmp_path / "out"), "--method", "none", "-q"])
    assert enhanced.exit_code == 0, enhanced.output
    (gammas,) = (tmp_path / "out").rglob("gammas.json")
    recorded = [f["content"] for f in json.loads(gammas.read_text())["frames"] if "content" in f]
    assert recorded == [area.summary()]  # the one area enhance used, from its first frame on
    as_png = runner.invoke(app, ["content", str(clip), "-o", str(tmp_path / "mask.png")])
    assert as_png.exit_code == 0, as_png.output
    png = cv2.imread(str(tmp_path / "mask.png"), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(png, area_image(area)) and set(np.unique(png)) == {0, OVERLAY, SCENE}


def test_bad_names_and_clips_fail_in_one_line_with_nothing_written(clip: Path, tmp_path: Path) -> None:
    named = runner.invoke(app, ["content", str(clip), "-o", str(tmp_path / "mask.jpg")])
    assert named.exit_code == 2 and ".pgm or .png" in named.output
    missing = runner.invoke(app, ["content", str(tmp_path / "none.mp4"), "-o", str(tmp_path / "m.pgm")])
    assert missing.exit_code == 1 and "none.mp4" in missing.output and "Traceback" not in missing.output
    (tmp_path / "text.mp4").write_text("not a video\n" * 20)
    text = runner.invoke(app, ["content", str(tmp_path / "text.mp4"), "-o", str(tmp_path / "m.pgm")])
    assert text.exit_code == 1 and "text.mp4" in text.output and "Traceback" not in text.output
    for seconds in ("nan", "inf", "-1"):
        odd = runner.invoke(app, ["content", str(clip), "-o", str(tmp_path / "m.pgm"), "--seconds", seconds])
        assert odd.exit_code == 2 and "--seconds" in odd.output, (seconds, odd.output)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["text.mp4"]  # no mask, no temporary left
    brief = runner.invoke(app, ["content", str(clip), "-o", str(tmp_path / "m.pgm"), "--seconds", "0.001"])
    assert brief.exit_code == 0 and "(1 frame)" in brief.output, brief.output  # at least one frame looked at


def test_a_hand_drawn_mask_reads_as_a_field_of_view_without_text(tmp_path: Path) -> None:
    mask = np.zeros((60, 80), np.uint8)
    cv2.circle(mask, (40, 30), 25, 255, -1)
    cv2.imwrite(str(tmp_path / "drawn.png"), mask)
    area = read_content_mask(tmp_path / "drawn.png")
    assert np.array_equal(area.fov, mask == 255) and not area.overlay.any()


@pytest.mark.parametrize(
    ("make", "says"),
    [
        (
            lambda p: cv2.imwrite(
                str(p), np.dstack([np.full((8, 8), 255, np.uint8)] * 2 + [np.zeros((8, 8), np.uint8)])
            ),
            "grey",
        ),
        (lambda p: cv2.imwrite(str(p), np.zeros((8, 8), np.uint8)), "no scene pixel"),
        (lambda p: p.write_bytes(b"P5\n8 8\n255\n"), "not a readable image"),
        (lambda p: os.mkfifo(p), "not a regular file"),
        (lambda p: None, "cannot read the content mask"),
    ],
    ids=["colour", "no-scene", "cut-short", "fifo", "missing"],
)
def test_a_bad_mask_is_refused_naming_the_file(tmp_path: Path, make: object, says: str) -> None:
    path = tmp_path / "mask.png"
    make(path)  # type: ignore[operator]
    with pytest.raises(InputError, match=says) as caught:
        read_content_mask(path)
    assert str(path) in str(caught.value) and "\n" not in str(caught.value)


def test_a_given_area_is_used_for_every_frame_of_its_size_only() -> None:
    area = ContentArea(np.pad(np.ones((4, 4), bool), 2), np.zeros((8, 8), bool))
    stream = ContentStream(create_method("none").stream(), area=area)
    frame = np.full((8, 8, 3), 90, np.uint8)
    (result,) = stream.push(frame)  # no frame held back for a detection
    assert result.info["content"] == area.summary()
    with pytest.raises(FrameShapeError, match="frame is 9x8, the content area given is 8x8"):
        stream.push(np.zeros((8, 9, 3), np.uint8))
    with pytest.raises(OptionError):
        ContentStream(create_method("none").stream(), area=area, resize="redetect")


def test_enhance_given_the_mask_writes_what_it_writes_finding_the_area(clip: Path, tmp_path: Path) -> None:
    """`enhance --content MASK` with the mask `content` wrote: the same frames and gammas as `--content auto`
    (which finds that area), the mask recorded with its hash; the same command resumes, an edited mask redoes
    the clip, and a mask of another size fails each clip in one line while the batch goes on."""
    mask = tmp_path / "scope.pgm"
    assert runner.invoke(app, ["content", str(clip), "-o", str(mask)]).exit_code == 0
    for name, content in (("auto", "auto"), ("mask", str(mask))):
        done = runner.invoke(app, ["enhance", str(clip), "-o", str(tmp_path / name), "--content", content, "-q"])
        assert done.exit_code == 0, done.output
    auto, given = (json.loads(next((tmp_path / n).rglob("gammas.json")).read_text()) for n in ("auto", "mask"))
    assert [f for f in auto["frames"]] == [f for f in given["frames"]]  # gammas, curves and the area's record
    for frame in (tmp_path / "auto").rglob("*.png"):
        assert frame.read_bytes() == (tmp_path / "mask" / frame.relative_to(tmp_path / "auto")).read_bytes()
    digest = given["settings"]["content"]["sha256"]
    assert given["settings"]["content"] == {"mask": str(mask), "sha256": digest} and len(digest) == 64
    again = runner.invoke(app, ["enhance", str(clip), "-o", str(tmp_path / "mask"), "--content", str(mask)])
    assert again.exit_code == 0 and "skipped clip (complete)" in again.output, again.output
    edited = bytearray(mask.read_bytes())
    edited[edited.index(SCENE)] = 0  # one scene pixel less (the header is ASCII): another mask
    mask.write_bytes(bytes(edited))
    redone = runner.invoke(app, ["enhance", str(clip), "-o", str(tmp_path / "mask"), "--content", str(mask)])
    assert redone.exit_code == 0 and "done    clip" in redone.output, redone.output
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.full((50, 40), SCENE, np.uint8))
    batch = tmp_path / "batch"
    batch.mkdir()
    for name in ("a.mp4", "b.mp4"):
        (batch / name).write_bytes(clip.read_bytes())
    wrong = runner.invoke(app, ["enhance", str(batch), "-o", str(tmp_path / "wrong"), "--content", str(small)])
    assert wrong.exit_code == 1
    for name in ("a.mp4", "b.mp4"):
        assert f"{name}: frame is 192x144, the content mask {small} is 40x50" in wrong.output, wrong.output
    unusable = runner.invoke(app, ["enhance", str(clip), "-o", str(tmp_path / "none"), "--content", str(batch)])
    assert unusable.exit_code == 2 and "content must be" in unusable.output, unusable.output
    assert not (tmp_path / "none").exists()


def test_stream_records_content_as_parsed(clip: Path, tmp_path: Path) -> None:
    """`stream --content AUTO` (any case, any spaces) ran, but its record took "AUTO" for a mask's path and
    stream.json was lost to "No such file or directory"; the options now hold the parsed word, or the mask's
    absolute path, as a clip's do."""
    from colonlight.live import StreamOptions

    assert StreamOptions(content=" AUTO").content == "auto"
    mask = tmp_path / "scope.pgm"
    assert runner.invoke(app, ["content", str(clip), "-o", str(mask)]).exit_code == 0
    assert StreamOptions(content=os.path.relpath(mask)).content == str(mask.absolute())
    out = tmp_path / "out"
    done = runner.invoke(app, ["stream", str(clip), "-o", str(out), "--content", " AUTO", "-m", "none", "-q"])
    assert done.exit_code == 0, done.output
    assert json.loads((out / "stream.json").read_text())["options"]["content"] == "auto"
