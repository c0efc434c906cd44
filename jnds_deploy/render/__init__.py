"""``jnds render``: camera-animated training/evaluation sequences rendered with Mitsuba 3."""

from .sequence import RenderConfig, render_sequence

__all__ = ["RenderConfig", "render_sequence"]
