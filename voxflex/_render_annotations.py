"""The 2-D annotations of a render, drawn with Pillow around the 3-D view.

Where each part of the picture goes (:class:`_Layout`: the title and step above the plot area, the colour bar
with its ticks on the right, the axes triad and the gravity arrow under it) and how each is drawn: text is
measured before it is placed, so labels stay inside the picture at any window size; frames are drawn as dots
and cables as polylines over the view.  Used by :mod:`voxflex.rendering`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ._render_style import _UP, _Camera, _Style

_AXIS_COLOURS = {"x": (205, 40, 40), "y": (30, 150, 40), "z": (40, 80, 220)}
_TEXT = (20, 20, 20)


CABLE_COLOUR = (214, 39, 40)
"""RGB of the cable polylines (no colour map of the renders reaches it: red, far from viridis)."""


# ---------------------------------------------------------------------------
# 2-D annotations
# ---------------------------------------------------------------------------
def _font(size: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=max(int(size), 6))
    except (TypeError, OSError, AttributeError):  # Pillow without FreeType: the fixed bitmap font
        return ImageFont.load_default()


def _text_size(font, text: str) -> tuple[int, int]:
    left, top, right, bottom = font.getbbox(text)
    return int(math.ceil(right - min(left, 0))), int(math.ceil(bottom - min(top, 0)))


def _fit_text(text: str, size: int, width: int, minimum: int = 7):
    """A font (shrunk down to ``minimum`` px) and the text (ellipsized if need be) that fit in ``width``."""
    while True:
        font = _font(size)
        if _text_size(font, text)[0] <= width or size <= minimum:
            break
        size -= 1
    if _text_size(font, text)[0] > width:
        while len(text) > 1 and _text_size(font, text + "…")[0] > width:
            text = text[:-1]
        text = text + "…" if text else ""
    return font, text


def _ticks(lo: float, hi: float, count: int = 5) -> list[float]:
    return [lo + (hi - lo) * i / (count - 1) for i in range(count)]


def _tick_text(v: float) -> str:
    return "0" if v == 0 else f"{v:.3g}"


@dataclass(frozen=True)
class _Layout:
    """Where each part of the picture goes (pixels)."""

    window: tuple[int, int]
    font: int
    title_h: int
    band_x: int  # left edge of the right band (colour bar, triad)
    band_w: int
    bar_box: tuple[int, int, int, int] | None  # x0, y0, x1, y1 of the colour gradient
    bar_title: str
    triad_box: tuple[int, int, int, int] | None
    gravity_box: tuple[int, int, int, int] | None

    @property
    def plot_size(self) -> tuple[int, int]:
        w, h = self.window
        return max(self.band_x, 8), max(h - self.title_h, 8)

    @classmethod
    def make(cls, style: _Style, result, clim, bar_title: str, has_gravity: bool) -> "_Layout":
        W, H = style.window
        f = int(np.clip(round(min(H * 0.04, W * 0.024)), 7, 28))
        pad = max(2, f // 3)
        title_h = int(2 * f * 1.25 + 2 * pad)
        font = _font(f)
        labels = [_tick_text(v) for v in _ticks(*clim)] if clim[1] > clim[0] else ["|u| = 0"]
        label_w = max(_text_size(font, t)[0] for t in labels)
        bar_w = max(6, int(0.8 * f))
        title_w = _text_size(font, bar_title)[0]
        band_w = 2 * pad + max(bar_w + pad + label_w, title_w)
        band_w = min(band_w, W // 3)
        legend = int(np.clip(4.5 * f, 24, H * 0.3))
        band_w = max(band_w, legend + 2 * pad) if style.show_axes or has_gravity else band_w
        band_w = min(band_w, W // 3)
        band_x = W - band_w
        y = title_h
        triad = gravity = None
        free = H - y - pad
        # the colour bar needs its title, a gradient at least 3 labels tall; the legends come below it
        bar_need = 2 * f + 3 * f
        if style.show_axes and free - legend >= bar_need:
            triad = (band_x + (band_w - legend) // 2, H - pad - legend, band_x + (band_w + legend) // 2, H - pad)
            free -= legend + pad
        if has_gravity and free - legend >= bar_need:
            top = (triad[1] if triad else H - pad) - pad - legend
            gravity = (band_x + (band_w - legend) // 2, top, band_x + (band_w + legend) // 2, top + legend)
            free -= legend + pad
        bar_top = y + int(1.9 * f)
        bar_bottom = min(y + free - f // 2, bar_top + max(10 * f, int(0.45 * H)))
        bar = None
        if bar_bottom - bar_top >= f:
            bar = (band_x + pad, bar_top, band_x + pad + bar_w, bar_bottom)
        return cls((W, H), f, title_h, band_x, band_w, bar, bar_title, triad, gravity)

    # -- drawing ----------------------------------------------------------
    def compose(self, view_image, style: _Style, result, step: int, cmap, clim, gravity, dots=None,
                cables=()) -> np.ndarray:
        from PIL import Image, ImageDraw

        W, H = self.window
        canvas = Image.new("RGB", (W, H), "white")
        canvas.paste(Image.fromarray(view_image), (0, self.title_h))
        draw = ImageDraw.Draw(canvas)
        width = max(2, round(self.font / 6))
        for line in cables:  # cables: polylines through the eyelets (pixels), always visible
            xy = [(float(x), float(y) + self.title_h) for x, y in line]
            if len(xy) >= 2:
                draw.line(xy, fill=CABLE_COLOUR, width=width, joint="curve")
        if dots is not None:  # affine frames: always visible, even inside the object
            r = max(2.0, self.font / 4)
            for x, y in dots:
                y = y + self.title_h
                draw.ellipse([x - r - 1, y - r - 1, x + r + 1, y + r + 1], fill="white")
                draw.ellipse([x - r, y - r, x + r, y + r], fill=(0, 0, 0))
        self._title(draw, style, result, step)
        self._colour_bar(draw, cmap, clim)
        if self.triad_box is not None:
            self._triad(draw, style.camera)
        if self.gravity_box is not None and gravity is not None:
            self._gravity(draw, style.camera, gravity)
        return np.asarray(canvas)

    def _title(self, draw, style, result, step):
        W = self.window[0]
        pad = max(2, self.font // 3)
        if _solver_kind(result) == "static":
            when = f"load factor {result.time[step]:.4g}"
        else:
            when = f"t = {result.time[step]:.4g} s"
        number = int(result.step[step]) if getattr(result, "step", None) is not None else step  # --every skips steps
        state = f"step {number}/{result.n_steps}, {when}"
        if not result.complete:  # a failed run's picture says so (it is not the answer the scene asked for)
            reason = " ".join(str(result.error).split()) or "no reason recorded"
            state = f"FAILED after step {result.n_steps}: {reason} | {state}"
        lines = [style.title, state]
        y = pad
        for text, size in zip(lines, (self.font + 1, self.font - 1)):
            font, text = _fit_text(text, size, W - 2 * pad)
            draw.text((pad, y), text, fill=_TEXT, font=font)
            y += int(self.font * 1.25)

    def _colour_bar(self, draw, cmap, clim):
        if self.bar_box is None:
            return
        x0, y0, x1, y1 = self.bar_box
        pad = max(2, self.font // 3)
        room = self.window[0] - x0 - pad
        font, title = _fit_text(self.bar_title, self.font, room)
        draw.text((x0, y0 - int(1.7 * self.font)), title, fill=_TEXT, font=font)
        lo, hi = clim
        if not hi > lo:
            font, text = _fit_text("|u| = 0" if self.bar_title.startswith("|u|") else "constant", self.font, room)
            draw.text((x0, y0), text, fill=_TEXT, font=font)
            return
        n = max(y1 - y0, 2)
        colours = (np.asarray(cmap(np.linspace(1.0, 0.0, n)))[:, :3] * 255).round().astype(int)
        for i, c in enumerate(colours):
            draw.line([(x0, y0 + i), (x1, y0 + i)], fill=tuple(int(v) for v in c))
        draw.rectangle([x0, y0, x1, y1], outline=(90, 90, 90))
        font = _font(self.font)
        room = self.window[0] - (x1 + pad) - 1
        for v in _ticks(lo, hi):
            yy = y1 - (v - lo) / (hi - lo) * (y1 - y0)
            draw.line([(x1, yy), (x1 + pad // 2 + 1, yy)], fill=(90, 90, 90))
            f, text = _fit_text(_tick_text(v), self.font, room)
            tw, th = _text_size(f, text)
            ty = int(np.clip(yy - th / 2 - 1, 0, self.window[1] - th - 1))
            draw.text((x1 + pad, ty), text, fill=_TEXT, font=f)

    def _arrow(self, draw, start, end, colour, width):
        draw.line([start, end], fill=colour, width=width)
        d = np.subtract(end, start).astype(float)
        length = float(np.hypot(*d))
        if length < 1:
            return
        d /= length
        n = np.array([-d[1], d[0]])
        head = min(0.35 * length, 3.0 * width + 4)
        base = np.asarray(end) - d * head
        draw.polygon([tuple(end), tuple(base + n * head * 0.45), tuple(base - n * head * 0.45)], fill=colour)

    def _triad(self, draw, cam: _Camera):
        x0, y0, x1, y1 = self.triad_box
        c = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
        arm = 0.34 * (x1 - x0)
        font = _font(max(self.font - 2, 7))
        width = max(1, self.font // 8)
        axes = []
        for name, e in _UP.items():
            e = np.asarray(e)
            axes.append((float(e @ cam.toward), name, np.array([e @ cam.right, -(e @ cam.up)])))
        for _, name, d in sorted(axes):  # the axis pointing away first, the one towards the camera last
            end = c + arm * d
            self._arrow(draw, tuple(c), tuple(end), _AXIS_COLOURS[name], width)
            tw, th = _text_size(font, name)
            length = float(np.hypot(*d))
            lab = c + (arm + 0.6 * self.font) * (d / length if length > 0.2 else np.array([0.7, -0.7]))
            lx = int(np.clip(lab[0] - tw / 2, x0, x1 - tw))
            ly = int(np.clip(lab[1] - th / 2, y0, y1 - th))
            draw.text((lx, ly), name, fill=_AXIS_COLOURS[name], font=font)

    def _gravity(self, draw, cam: _Camera, g):
        x0, y0, x1, y1 = self.gravity_box
        c = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
        d_unit = g / np.linalg.norm(g)
        d = np.array([d_unit @ cam.right, -(d_unit @ cam.up)])
        arm = 0.32 * (x1 - x0)
        width = max(2, self.font // 6)
        length = float(np.hypot(*d))
        colour = (40, 40, 40)
        if length > 0.25:
            self._arrow(draw, tuple(c - arm * d), tuple(c + arm * d), colour, width)
        else:  # gravity along the line of sight: a dot (towards the viewer) or a cross (away)
            r = 0.18 * (x1 - x0)
            draw.ellipse([c[0] - r, c[1] - r, c[0] + r, c[1] + r], outline=colour, width=width)
            if float(d_unit @ cam.toward) > 0:
                draw.ellipse([c[0] - r / 4, c[1] - r / 4, c[0] + r / 4, c[1] + r / 4], fill=colour)
            else:
                k = r * 0.7
                draw.line([(c[0] - k, c[1] - k), (c[0] + k, c[1] + k)], fill=colour, width=width)
                draw.line([(c[0] - k, c[1] + k), (c[0] + k, c[1] - k)], fill=colour, width=width)
        text = f"g = {np.linalg.norm(g):.3g} m/s^2"
        f, text = _fit_text(text, max(self.font - 2, 7), x1 - x0 + (self.window[0] - x1) - 2)
        tw, th = _text_size(f, text)
        draw.text((int(max(x0, min(c[0] - tw / 2, self.window[0] - tw - 1))), y0), text, fill=colour, font=f)


def _solver_kind(result) -> str:
    """``static`` or ``implicit-euler``: the run's solver (``/problem``; static where not recorded)."""
    return str(result.problem.get("solver_kind", "static"))
