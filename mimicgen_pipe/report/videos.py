"""What generated demos look like: the render stage's GIFs and MP4s."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from mimicgen_pipe.report.blocks import Block, Heading, Image, Text
from mimicgen_pipe.report.inputs import Media


def video_blocks(
    task: str, variants: Sequence[str], media: Mapping[str, Media], folder: str
) -> list[Block]:
    """The render stage's GIFs per variant (first kept and first failed episode), referred to
    from the report's folder as ``folder``/<task>_<variant>/<kept|failed>_0.gif, with their
    MP4s. ``media``: variant -> its videos; variants without videos are left out."""
    blocks: list[Block] = []
    for v in variants:
        m = media.get(v)
        if not m:
            continue
        blocks.append(Heading(3, f"{task} {v}"))
        for kind in ("kept", "failed"):
            if f"{kind}_0.gif" in m.files:
                blocks.append(Image(f"{folder}/{task}_{v}/{kind}_0.gif", f"{kind} episode, {v}"))
        mp4s = ", ".join(
            f"`{folder}/{task}_{v}/{f}`" for f in sorted(m.files) if f.endswith(".mp4")
        )
        blocks.append(Text(f"Videos: {mp4s or 'none'}."))
    if not blocks:
        return []
    return [
        Heading(2, "What generated demos look like"),
        Text(
            "The first kept and the first failed generated episode of each variant, replayed "
            "from their stored states (render stage); the caption names the subtask and the "
            "source demo its segment was taken from. Times per frame: `timings/`."
        ),
        *blocks,
    ]
