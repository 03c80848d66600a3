"""Draw docs/layers.png: the package's rooms and every import between them, read from the source.

The rooms and edges are the ones tests/test_architecture.py checks (every import, inside functions
too). Layers run top to bottom (the command line, then the shell, flows, tasks, schemas, lib); lib's
rooms are placed in rows by how far down the import graph they sit, so every arrow inside lib points
down or sideways, never up.

    .venv/bin/python scripts/draw_layers.py [--out docs/layers.png]
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.support.import_graph import find_modules, imported, room  # noqa: E402

SHELL = ("demoforge.cli", "demoforge.runtime", "demoforge.bench")
LAYER_ROWS = [("command line", ["demoforge.cli"]), ("application shell", ["demoforge.runtime", "demoforge.bench"]),
              ("flows/", ["demoforge.flows"]), ("report/", ["demoforge.report"]), ("tasks/", ["demoforge.tasks"]),
              ("schemas/", ["demoforge.schemas"])]


MODULES = find_modules(ROOT)


def room_edges() -> dict[str, dict[str, int]]:
    """{room: {room it imports: number of module-to-module imports}}."""
    edges: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
    for m, p in MODULES.items():
        for t in {t for t, _, _ in imported(m, p, MODULES)}:
            a, b = room(m), room(t)
            if a != b:
                edges[a][b] += 1
    return edges


def lib_rows(edges: dict[str, dict[str, int]]) -> list[list[str]]:
    """lib's rooms by depth: a room sits one row above the deepest room it imports (the graph has no loop)."""
    rooms = sorted({room(m) for m in MODULES if m.startswith("demoforge.lib.")} | {"demoforge.lib"})
    depth: dict[str, int] = {}

    def level(r: str) -> int:
        if r not in depth:
            depth[r] = 0  # a loop would recurse forever; the architecture test rules it out
            depth[r] = 1 + max((level(t) for t in edges.get(r, {}) if t in rooms), default=-1)
        return depth[r]

    for r in rooms:
        level(r)
    rows: dict[int, list[str]] = defaultdict(list)
    for r in rooms:
        rows[depth[r]].append(r)
    return [sorted(rows[d]) for d in sorted(rows, reverse=True)]


def draw(out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import FancyBboxPatch

    edges = room_edges()
    rows = [(label, rooms) for label, rooms in LAYER_ROWS]
    rows += [("lib/", r) for r in lib_rows(edges)]
    pos: dict[str, tuple[float, float]] = {}
    box_w: dict[str, float] = {}
    width = 2.2 * max(len(r) for _, r in rows)
    for y, (_, rooms) in enumerate(rows):
        for x, room in enumerate(rooms):
            pos[room] = ((x + 0.5) * width / len(rooms), -y * 1.6)
            box_w[room] = min(1.9, 0.9 * width / len(rooms))
    fig, ax = plt.subplots(figsize=(width + 2, 1.3 * len(rows) + 1))
    colours = {"demoforge.lib": "#dbe9f6", "demoforge.schemas": "#fde6c8", "demoforge.tasks": "#e3f1d9",
               "demoforge.flows": "#f6dbe9"}
    for src, targets in edges.items():
        for dst, n in targets.items():
            if src in pos and dst in pos:
                (x0, y0), (x1, y1) = pos[src], pos[dst]
                ax.annotate("", xy=(x1, y1 + 0.3), xytext=(x0, y0 - 0.3),
                            arrowprops=dict(arrowstyle="->", lw=0.4 + 0.15 * min(n, 12), alpha=0.35, color="#444"))
    for room, (x, y) in pos.items():
        layer = ".".join(room.split(".")[:2])
        ax.add_patch(FancyBboxPatch((x - box_w[room] / 2, y - 0.3), box_w[room], 0.6, boxstyle="round,pad=0.02",
                                    fc=colours.get(layer, "#eeeeee"), ec="#333", lw=0.8))
        name = room.replace("demoforge.", "").replace("lib.", "lib/") + ("/__init__" if room == "demoforge.lib" else "")
        ax.text(x, y, name, ha="center", va="center", fontsize=8)
    for y, (label, _) in enumerate(rows):
        ax.text(-0.2, -y * 1.6, label, ha="right", va="center", fontsize=8, color="#555")
    ax.set_xlim(-1.6, width + 0.2)
    ax.set_ylim(-(len(rows) - 1) * 1.6 - 0.8, 0.8)
    ax.axis("off")
    n_edges = sum(len(t) for t in edges.values())
    ax.set_title(f"demoforge: {len(pos)} rooms, {n_edges} room-to-room imports (arrow: imports; "
                 f"width: how many module imports)", fontsize=10)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "layers.png", help="the picture to write")
    draw(ap.parse_args().out)


if __name__ == "__main__":
    main()
