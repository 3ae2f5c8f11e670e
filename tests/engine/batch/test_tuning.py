"""Process-wide tuning (torch threads, glibc malloc, the GC) is applied at a process's entry, never by the
library: ``run_batch`` leaves the caller's settings as they were, ``colonlight enhance`` sets them (issue 15)."""

from __future__ import annotations

import gc
import json
import subprocess
import sys
from pathlib import Path

from ...media import make_clip


def test_run_batch_leaves_process_settings_alone(tmp_path: Path, random_weights: Path) -> None:
    import torch

    from colonlight import ClipOptions, MethodSpec, discover_clips, network_threads, run_batch

    spec = MethodSpec.of("rnn", weights=str(random_weights), device="cpu")
    assert network_threads(spec, 1) == 1  # what the CLI would set: the check below sees a change
    clip = make_clip(tmp_path / "c.mp4", n_frames=12, fps=25)
    before_threads = torch.get_num_threads()
    torch.set_num_threads(3)
    try:
        thresholds, frozen = gc.get_threshold(), gc.get_freeze_count()
        outcomes = run_batch(discover_clips([clip], tmp_path / "out"), spec, ClipOptions(), tmp_path / "out")
        assert [o.status for o in outcomes] == ["done"]
        assert torch.get_num_threads() == 3
        assert gc.get_threshold() == thresholds
        # gc.freeze() would add every object tracked since the last one (thousands at least). The count may fall a
        # little: objects an earlier in-process command froze can die meanwhile (33 did in a two-process run).
        assert gc.get_freeze_count() <= frozen
    finally:
        torch.set_num_threads(before_threads)


def _cli_in_a_process(code: str) -> dict[str, object]:
    """Run ``code`` (which sets ``result``) in a fresh interpreter and return ``result``."""
    script = f"import json\n{code}\nprint(json.dumps(result))"
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])  # type: ignore[no-any-return]


def test_enhance_entry_sets_torch_threads(tmp_path: Path, random_weights: Path) -> None:
    clip = make_clip(tmp_path / "c.mp4", n_frames=12, fps=25)
    result = _cli_in_a_process(
        "import gc, torch\n"
        "torch.set_num_threads(3)\n"
        "from typer.testing import CliRunner\n"
        "from colonlight_cli.main import app\n"
        f"r = CliRunner().invoke(app, ['enhance', {str(clip)!r}, '-o', {str(tmp_path / 'out')!r}, '-q', "
        f"'--weights', {str(random_weights)!r}])\n"
        "result = {'code': r.exit_code, 'threads': torch.get_num_threads(), 'frozen': gc.get_freeze_count()}"
    )
    assert result["code"] == 0
    assert result["threads"] == 1  # the small recurrent net: one thread (colonlight.tuning.network_threads)
    assert isinstance(result["frozen"], int) and result["frozen"] > 0  # the imports frozen out of the GC's sight


def test_enhance_without_torch_never_imports_it(tmp_path: Path) -> None:
    clip = make_clip(tmp_path / "c.mp4", n_frames=6, fps=25)
    result = _cli_in_a_process(
        "import sys\n"
        "from typer.testing import CliRunner\n"
        "from colonlight_cli.main import app\n"
        f"r = CliRunner().invoke(app, ['enhance', {str(clip)!r}, '-o', {str(tmp_path / 'out')!r}, '-q', "
        "'--method', 'none'])\n"
        "result = {'code': r.exit_code, 'torch': 'torch' in sys.modules}"
    )
    assert result == {"code": 0, "torch": False}
