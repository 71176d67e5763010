"""Write docs/field-guide.md and one SVG picture per pose of every built-in plan.

Usage: ``python scripts/make_field_guide.py [DOCS_DIR]`` (default: the repository's docs/).
The test ``tests/procedure/test_pose_picture.py`` fails when the committed guide is stale.
"""

from __future__ import annotations

import sys
from pathlib import Path

from canimucal.runtime.plan_forecast import field_guide_pages


def main(argv: list[str]) -> int:
    """Write the guide into ``argv[0]`` (default docs/); return the exit status."""
    docs = Path(argv[0]) if argv else Path(__file__).resolve().parent.parent / "docs"
    markdown, pictures = field_guide_pages()
    (docs / "field-guide").mkdir(parents=True, exist_ok=True)
    for name, svg in pictures.items():
        (docs / "field-guide" / name).write_text(svg, encoding="utf-8")
    (docs / "field-guide.md").write_text(markdown, encoding="utf-8")
    print(f"wrote {docs / 'field-guide.md'} and {len(pictures)} pictures")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
