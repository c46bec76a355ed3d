"""Draw only what changed since the last frame: the rest of the picture is reused.

While a handle or a slider is dragged, one primitive changes from frame to frame and the
others, the target and the background do not; on software OpenGL (VMs, Xvfb, remote
desktops) drawing those costs more than half of every frame (BENCHMARKS.md, issue 16).
CAD viewers keep such a scene's picture and draw only the moving part over it
(OpenCascade's "immediate mode" layer); this module does that for a VTK render window:

- a *capture* frame draws the unchanged opaque actors in the main renderer as usual,
  copies the picture (colour and depth) into a framebuffer of its own, then draws the
  *live* actors (those that changed, everything translucent, 2D props) in a second
  renderer over it, depth-tested against that picture;
- the frames after it, as long as only live actors change and the view does not,
  *reuse* the picture: they copy it back instead of drawing the main renderer, and draw
  the live actors over it.

The result is the plain frame, pixel for pixel: the same opaque geometry against the same
depth, then the same translucent pass and 2D props (tests/app/test_frame_reuse.py).

The main renderer keeps every actor at all times, so pickers, bounds and code that adds
or removes actors see the scene as it is. A live actor is drawn by a stand-in in the
second renderer that shares its mapper and property; the original is hidden only while
a frame renders. (Moving an actor between renderers would release its GPU buffers.)
"""

from __future__ import annotations

from typing import Any

import vtk
from vtkmodules.vtkRenderingOpenGL2 import vtkOpenGLFramebufferObject

# OpenGL enums (not wrapped by VTK's Python layer).
GL_READ_FRAMEBUFFER = 0x8CA8
GL_DRAW_FRAMEBUFFER = 0x8CA9
GL_COLOR_BUFFER_BIT = 0x4000
GL_DEPTH_BUFFER_BIT = 0x0100
GL_NEAREST = 0x2600

PLAIN, CAPTURE, REUSE = "plain", "capture", "reuse"


class FrameReuse:
    """Reuses a render window's picture of its main renderer's unchanged opaque actors.

    `live` is a renderer of its own at layer `layer` (which must exist in the window),
    between the main renderer and any overlay above it. Call `begin_frame` at the start
    of every frame (the render window's StartEvent, after the camera is final) and
    nothing else; `counts` says how many frames each way went, and `enabled` False draws
    every frame in full (keeping the picture while nothing in it changes). With FXAA,
    multisampling or a custom render pass (a GPU's settings) every frame is drawn in full
    too: the copy would not reproduce them."""

    def __init__(self, render_window: Any, main: vtk.vtkRenderer, layer: int) -> None:
        self.window = render_window
        self.main = main
        self.live = vtk.vtkRenderer()
        self.live.SetLayer(layer)
        self.live.InteractiveOff()
        self.live.PreserveColorBufferOn()  # draws over the picture the frame starts with
        self.live.PreserveDepthBufferOn()
        self.live.AutomaticLightCreationOff()
        self.live.SetLightCollection(main.GetLights())
        render_window.AddRenderer(self.live)
        self.enabled = _can_blit(render_window)
        self.counts = {PLAIN: 0, CAPTURE: 0, REUSE: 0}
        self.mode = PLAIN
        self._cache: vtkOpenGLFramebufferObject | None = None
        self._cache_size = (0, 0)
        self._valid = False  # the cache holds the picture of the current view
        self._view: tuple = ()
        self._props: list[Any] = []
        self._stamps: dict[int, int] = {}  # id(prop) -> its redraw time after the last frame
        self._shown: set[int] = set()  # ids of the props visible in the last frame
        self._under_state: tuple = ()
        self._live_ids: set[int] = set()
        self._stand_ins: dict[int, vtk.vtkActor] = {}  # id(original) -> stand-in
        self._hidden: list[Any] = []  # originals hidden for this frame
        self._observers = [
            (self.live, self.live.AddObserver("StartEvent", self._before_live)),
            (render_window, render_window.AddObserver("EndEvent", self._after_frame)),
        ]

    # -- per frame ------------------------------------------------------------------------
    def begin_frame(self) -> None:
        """Decide how this frame is drawn; hide what the main renderer must not draw."""
        props = self._props = _props(self.main)  # kept: ids stay those of live wrappers
        view = self._view_state(props)
        visible = [p for p in props if p.GetVisibility()]
        # What changed and is, or was, in the picture (hidden before and now: nothing).
        seen = {id(p) for p in visible} | self._shown
        changed = {id(p) for p in props
                   if self._stamps.get(id(p)) != p.GetRedrawMTime() and id(p) in seen}
        opaque = [p for p in visible if _opaque_actor(p)]
        under = self._under()
        same_view = view == self._view and _drawn_state(under) == self._under_state
        self._view = view
        opaque_ids = {id(p) for p in opaque}
        # What changed stays live with what was live before: a drag's next move, or
        # the other half of a mirrored pair, then needs no new picture.
        live_opaque = (changed | self._live_ids) & opaque_ids
        if 2 * len(live_opaque) > len(opaque_ids):
            live_opaque = changed & opaque_ids
        if not (same_view and self._usable()):
            self._forget()
            self._set_mode(PLAIN, set(), props, changed, under)
        elif not self.enabled:
            # In full, keeping the picture while nothing in it changes.
            if not changed <= self._live_ids:
                self._forget()
            self._set_mode(PLAIN, set(), props, changed, under)
        elif self._valid and self._cache is not None and changed <= self._live_ids:
            self._set_mode(REUSE, self._live_ids, props, changed, under)
        elif changed and 2 * len(live_opaque) <= len(opaque_ids):
            # Live: the changed opaque actors, and all that is not opaque.
            self._live_ids = {id(p) for p in visible} - (opaque_ids - live_opaque)
            self._set_mode(CAPTURE, self._live_ids, props, changed, under)
        else:
            self._forget()
            self._set_mode(PLAIN, set(), props, changed, under)
        self.counts[self.mode] += 1

    def _forget(self) -> None:
        """The picture no longer shows the scene: take a new one when next possible."""
        self._valid = False
        self._live_ids = set()

    def _set_mode(self, mode: str, live_ids: set[int], props: list[Any],
                  changed: set[int], under: list[vtk.vtkRenderer]) -> None:
        """Draw this frame as `mode`, the props `live_ids` by their stand-ins."""
        self.mode = mode
        self.main.SetDraw(mode != REUSE)
        # Renderers between the main one and the live one (the orientation axes) are in
        # the picture too; what they show is compared after each frame (_after_frame),
        # and they are assumed to change with nothing else (_drawn_state).
        for renderer in under:
            renderer.SetDraw(mode != REUSE)
        self.live.SetActiveCamera(self.main.GetActiveCamera())
        _copy_renderer_settings(self.main, self.live)
        for prop in props:
            key = id(prop)
            live = key in live_ids and prop.GetVisibility()
            stand_in = self._stand_ins.get(key)
            if live:
                if stand_in is None:
                    stand_in = self._stand_ins[key] = prop.NewInstance()
                    self.live.AddViewProp(stand_in)
                    changed.add(key)
                if key in changed:  # (a replaced mapper or property changes it too)
                    stand_in.ShallowCopy(prop)
                    stand_in.PickableOff()
                # Only when it changes: a modified actor makes its mapper upload anew.
                stand_in.SetVisibility(True)
                prop.VisibilityOff()
                self._hidden.append(prop)
            elif stand_in is not None:
                stand_in.VisibilityOff()
        # Stand-ins of props no longer in the main renderer go.
        present = {id(p) for p in props}
        for key in [k for k in self._stand_ins if k not in present]:
            self.live.RemoveViewProp(self._stand_ins.pop(key))

    def _before_live(self, *_: Any) -> None:
        """The live renderer starts: keep the picture drawn so far, or put it back."""
        if self.mode == CAPTURE:
            self._valid = self._copy(to_cache=True)
            if not self._valid:  # no copy: fall back to the plain frame's contents
                self.counts[CAPTURE] -= 1
                self.counts[PLAIN] += 1
        elif self.mode == REUSE and not self._copy(to_cache=False):
            self._valid = False  # the window lost its framebuffer: the next frame in full

    def _after_frame(self, *_: Any) -> None:
        for prop in self._hidden:
            prop.VisibilityOn()
        self._hidden.clear()
        self.main.SetDraw(True)
        under = self._under()
        for renderer in under:
            renderer.SetDraw(True)
        # After the visibility toggles, so that only later edits count as changes; and
        # after the frame, which may have moved the axes' camera along with the main one.
        props = _props(self.main)
        self._stamps = {id(p): p.GetRedrawMTime() for p in props}
        self._shown = {id(p) for p in props if p.GetVisibility()}
        self._under_state = _drawn_state(under)

    def _under(self) -> list[vtk.vtkRenderer]:
        """The window's renderers between the main renderer's layer and the live one's."""
        low, high = self.main.GetLayer(), self.live.GetLayer()
        return [r for r in _items(self.window.GetRenderers())
                if r is not self.main and low <= r.GetLayer() < high]

    # -- the picture ------------------------------------------------------------------------
    def _usable(self) -> bool:
        """Whether the main renderer draws in a way the copy reproduces exactly."""
        main = self.main
        return (not main.GetUseFXAA() and main.GetPass() is None
                and self.window.GetMultiSamples() == 0)

    def _copy(self, to_cache: bool) -> bool:
        """Copy colour and depth between the window's render framebuffer and the cache."""
        render_fb = self.window.GetRenderFramebuffer()
        if render_fb is None:
            return False
        w, h = self.window.GetSize()
        if w <= 0 or h <= 0:
            return False
        if to_cache and (self._cache is None or self._cache_size != (w, h)):
            self._release()
            cache = vtkOpenGLFramebufferObject()
            cache.SetContext(self.window)
            cache.SaveCurrentBindingsAndBuffers()
            ok = cache.PopulateFramebuffer(w, h, True, 1, vtk.VTK_UNSIGNED_CHAR, True, 32, 0,
                                             bool(self.window.GetStencilCapable()))
            cache.RestorePreviousBindingsAndBuffers()
            if not ok:
                return False
            self._cache, self._cache_size = cache, (w, h)
        if self._cache is None:
            return False
        source, target = (render_fb, self._cache) if to_cache else (self._cache, render_fb)
        # Through the GL state: its blit ignores the scissor box the last renderer left
        # (the static vtkOpenGLFramebufferObject.Blit copied only the orientation axes'
        # corner).
        source.Bind(GL_READ_FRAMEBUFFER)
        target.Bind(GL_DRAW_FRAMEBUFFER)
        self.window.GetState().vtkglBlitFramebuffer(
            0, 0, w, h, 0, 0, w, h, GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT, GL_NEAREST)
        render_fb.Bind()  # draw and read, as the frame had it
        return True

    def _view_state(self, props: list[Any]) -> tuple:
        """What, when it changes, makes the picture stale whatever the actors do."""
        return (tuple(self.window.GetSize()), tuple(self.main.GetViewport()),
                tuple(self.main.GetBackground()), _camera_state(self.main.GetActiveCamera()),
                tuple(light.GetMTime() for light in _items(self.main.GetLights())),
                tuple(id(p) for p in props))

    def _release(self) -> None:
        if self._cache is not None:
            self._cache.ReleaseGraphicsResources(self.window)
        self._cache, self._cache_size, self._valid = None, (0, 0), False

    def close(self) -> None:
        """Stop: remove the observers, the live renderer and the cached picture."""
        for obj, tag in self._observers:
            obj.RemoveObserver(tag)
        self._observers = []
        self._after_frame()
        self._release()
        self.live.RemoveAllViewProps()
        self._stand_ins.clear()
        self.window.RemoveRenderer(self.live)


def _drawn_state(renderers: list[vtk.vtkRenderer]) -> tuple:
    """What decides the pictures of `renderers` (the orientation axes' corner): viewport,
    camera, and which props are shown. Not the props' modification times: vtkAxesActor
    modifies itself whenever it is drawn, with nothing new to show. (By address: nothing
    may hold these Python wrappers, so their ids can change.)"""
    state = []
    for r in renderers:
        state.append((r.GetAddressAsString("vtkObject"), r.GetLayer(), tuple(r.GetViewport()),
                      _camera_state(r.GetActiveCamera()),
                      tuple((p.GetAddressAsString("vtkObject"), p.GetVisibility())
                            for p in _props(r))))
    return tuple(state)


def _camera_state(c: vtk.vtkCamera) -> tuple:
    """Everything of a camera that decides where things land on screen, and at what depth."""
    return (c.GetPosition(), c.GetFocalPoint(), c.GetViewUp(), c.GetViewAngle(),
            c.GetParallelProjection(), c.GetParallelScale(), c.GetClippingRange(),
            c.GetWindowCenter())


def _items(collection: vtk.vtkCollection) -> list[Any]:
    return [collection.GetItemAsObject(i) for i in range(collection.GetNumberOfItems())]


def _props(renderer: vtk.vtkRenderer) -> list[Any]:
    return _items(renderer.GetViewProps())


def _opaque_actor(prop: Any) -> bool:
    """A 3D actor with nothing translucent to draw (translucent geometry is blended in a
    later pass, so it cannot sit in the reused picture under what is drawn live)."""
    return (isinstance(prop, vtk.vtkActor) and prop.GetMapper() is not None
            and not prop.HasTranslucentPolygonalGeometry())


def _copy_renderer_settings(main: vtk.vtkRenderer, live: vtk.vtkRenderer) -> None:
    """The shading and translucency settings that decide how the live actors look."""
    live.SetTwoSidedLighting(main.GetTwoSidedLighting())
    live.SetLightFollowCamera(main.GetLightFollowCamera())
    live.SetUseOIT(main.GetUseOIT())
    live.SetUseDepthPeeling(main.GetUseDepthPeeling())
    live.SetMaximumNumberOfPeels(main.GetMaximumNumberOfPeels())
    live.SetOcclusionRatio(main.GetOcclusionRatio())
    live.SetUseShadows(main.GetUseShadows())
    live.SetAmbient(main.GetAmbient())
    live.SetViewport(main.GetViewport())


def _can_blit(render_window: Any) -> bool:
    return hasattr(render_window, "GetRenderFramebuffer")
