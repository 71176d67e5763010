"""Write docs/field-guide.md and one SVG picture per pose of every built-in plan.

Usage: ``python scripts/make_field_guide.py [DOCS_DIR]`` (default: the repository's docs/).
The test ``tests/procedure/test_pose_picture.py`` fails when the committed guide is stale.
"""

from __future__ import annotations

import sys
from pathlib import Path

from canimucal.model.vocabulary.plans import builtin_names, builtin_plan
from canimucal.procedure.pose_picture import field_guide


def main(argv: list[str]) -> int:
    """Write the guide into ``argv[0]`` (default docs/); return the exit status."""
    docs = Path(argv[0]) if argv else Path(__file__).resolve().parent.parent / "docs"
    markdown, pictures = field_guide([builtin_plan(name) for name in builtin_names()])
    (docs / "field-guide").mkdir(parents=True, exist_ok=True)
    for name, svg in pictures.items():
        (docs / "field-guide" / name).write_text(svg, encoding="utf-8")
    (docs / "field-guide.md").write_text(markdown, encoding="utf-8")
    print(f"wrote {docs / 'field-guide.md'} and {len(pictures)} pictures")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
