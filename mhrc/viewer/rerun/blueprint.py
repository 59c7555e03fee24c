"""The recording's default layout (a Rerun blueprint, sent with the data): the house in 3D, a text panel
per robot, the progress plot, and the messages and events beside them."""

from __future__ import annotations

import rerun.blueprint as rrb


def blueprint(robots: tuple[str, ...]) -> rrb.Blueprint:
    """The 3D view on the left; on the right one text log per robot (its thoughts, actions, outcomes and
    inbox), the messages and events, and the progress plot (placed objects, partial success)."""
    texts = [rrb.TextLogView(origin=f"agents/{r}", name=r) for r in robots]
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="world", name="house"),
            rrb.Vertical(
                *(texts or [rrb.TextLogView(origin="agents", name="robots")]),
                rrb.Tabs(
                    rrb.TextLogView(origin="messages", name="messages"),
                    rrb.TextLogView(origin="events", name="events"),
                ),
                rrb.TimeSeriesView(origin="progress", name="progress"),
            ),
            column_shares=[3, 2],
        ),
        rrb.TimePanel(timeline="tick"),
        collapse_panels=False,
    )
