"""The shipped checkpoint's artifacts, packaged: exported and int8-calibrated once at
release, so that `jnds run`, `serve` and `batch` run without torch and without --artifacts
(``runtime.config.SHIPPED_ARTIFACTS``).

    python -m tools.package_artifacts        # rewrites jnds_deploy/checkpoints/artifacts

The recipe is ``build``'s: `jnds export` of the shipped checkpoint, then `jnds calibrate
--method qat` on the first three frames of the bundled sample. The tests build the same
and hold the packaged graphs equal to it byte for byte (tests/test_packaged.py).
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "samples" / "orbit-160x90"
CALIBRATION_FRAMES = 3


def build(out: str | Path) -> Path:
    """Export and calibrate the shipped checkpoint into ``out``; returns it."""
    from jnds_deploy.calibration import CalibrateConfig, calibrate
    from jnds_deploy.export import ExportConfig, export

    out = Path(out)
    export(ExportConfig(out=str(out)), log=lambda s: None)
    calibrate(
        CalibrateConfig(artifacts=str(out), data=(str(SAMPLE),), method="qat", frames=CALIBRATION_FRAMES),
        log=lambda s: None,
    )
    return out


def main() -> int:
    from jnds_deploy.runtime.config import SHIPPED_ARTIFACTS

    target = Path(SHIPPED_ARTIFACTS)
    tmp = target.with_name(target.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    build(tmp)
    shutil.rmtree(target, ignore_errors=True)
    tmp.rename(target)
    print(f"wrote {target}: {', '.join(sorted(p.name for p in target.iterdir()))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
