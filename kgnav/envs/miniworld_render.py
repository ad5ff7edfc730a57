"""A :class:`~kgnav.envs.miniworld_house.House` drawn by MiniWorld: RGB, z-depth and labels.

MiniWorld (``miniworld==2.1``, OpenGL through pyglet) renders the colour frame as it always
does. Depth and semantic labels come from a second pass of the same scene, same camera, into an
off-screen buffer of this module (24-bit depth, no multisampling) in which lighting and
textures are off and fog of infinite density paints every fragment in the fog colour: black
for the rooms, and for each object a colour that encodes its instance id. Every pixel of that
pass therefore names the surface the depth buffer kept, so labels and depth agree per pixel;
at object edges the RGB frame's anti-aliasing blends colours the labels do not.

Headless: ``pyglet.options["headless"] = True`` before pyglet is imported (an EGL context, no
display; on Debian the packages libegl1 libegl-mesa0 libgl1-mesa-dri libglu1-mesa). MiniWorld
is imported here only, when the first frame is asked for, so kgnav works without it.

pyglet shares display lists between its contexts and MiniWorld compiles every world's static
geometry into list 1, so a world recompiles it when another world drew last. The label pass
draws its rooms from a display list of its own (an id from ``glGenLists``, so no world
overwrites another's), compiled once: drawn command by command they cost 1.4 ms a frame.

Labels are read back only when asked for (``render(..., labels=True)``): depth comes from the
same pass either way, so a frame without labels has the same depth, bit for bit.

Loading MiniWorld's textures through pyglet converted each image to RGBA with a regular
expression per pixel: 10 s per process, more than a whole short run. :func:`_fast_textures`
converts the same decoded pixels with numpy instead (same bytes uploaded).
"""

from __future__ import annotations

import contextlib
import ctypes
import io
import os

import numpy as np

from kgnav.envs.miniworld_house import CEILING_TEXTURE, WALL_HEIGHT, House
from kgnav.errors import KgnavError

MESA_PACKAGES = "libegl1 libegl-mesa0 libgl1-mesa-dri libglu1-mesa"
_NEAR, _FAR = 0.05, 50.0  # the label pass's clip planes (MiniWorld's RGB pass: 0.04, 100)
_LAST: list = [None]  # the world whose static geometry display list 1 holds now


@contextlib.contextmanager
def _fast_textures(gl, opengl):
    """MiniWorld's ``Texture.load`` with the image's pixels converted by numpy, not pyglet's
    per-pixel regular expression; the GL calls and the bytes uploaded are MiniWorld's."""
    cls = opengl.Texture
    original = cls.__dict__["load"]

    def load(_cls, tex_path):
        import pyglet

        img = pyglet.image.load(tex_path)
        tex = img.get_texture()
        gl.glEnable(tex.target)
        gl.glBindTexture(tex.target, tex.id)
        rgba = _rgba_rows(img.get_image_data())
        gl.glTexImage2D(gl.GL_TEXTURE_2D, 0, gl.GL_RGB, img.width, img.height, 0, gl.GL_RGBA,
                        gl.GL_UNSIGNED_BYTE, rgba.ctypes.data_as(ctypes.POINTER(gl.GLubyte)))
        gl.glHint(gl.GL_GENERATE_MIPMAP_HINT, gl.GL_NICEST)
        gl.glGenerateMipmap(gl.GL_TEXTURE_2D)
        gl.glTexParameteri(gl.GL_TEXTURE_2D, gl.GL_TEXTURE_MAG_FILTER, gl.GL_LINEAR)
        gl.glTexParameteri(gl.GL_TEXTURE_2D, gl.GL_TEXTURE_MIN_FILTER,
                           gl.GL_LINEAR_MIPMAP_LINEAR)
        gl.glBindTexture(gl.GL_TEXTURE_2D, 0)
        return tex

    cls.load = classmethod(load)
    try:
        yield
    finally:
        cls.load = original


def _rgba_rows(data) -> np.ndarray:
    """The pixels of a pyglet ``ImageData`` as ``get_data("RGBA", 4 * width)`` returns them:
    rows bottom to top, and a component the format lacks taken from its first one (pyglet's
    rule: RGB gives A = R, L gives L, L, L, L)."""
    fmt, pitch, w, h = data.format, data.pitch, data.width, data.height
    raw = np.frombuffer(data.get_data(fmt, pitch), np.uint8)  # no conversion: as decoded
    px = raw.reshape(h, abs(pitch))[:, :w * len(fmt)].reshape(h, w, len(fmt))
    if pitch < 0:  # stored top to bottom
        px = px[::-1]
    return np.ascontiguousarray(px[..., [fmt.index(c) if c in fmt else 0 for c in "RGBA"]])


def _modules():
    """(pyglet.gl, miniworld.miniworld, miniworld.entity, miniworld.opengl), importing them
    headless."""
    try:
        import pyglet
    except ImportError:
        raise KgnavError("environment 'miniworld' needs pyglet: pip install "
                         "'kgnav[miniworld]'") from None
    pyglet.options["headless"] = True
    try:
        from miniworld import entity, miniworld
        from pyglet import gl
    except ImportError as e:
        raise KgnavError(f"environment 'miniworld' needs the MiniWorld simulator "
                         f"(pip install 'kgnav[miniworld]'): {e}") from None
    except Exception as e:  # no EGL library, no usable OpenGL driver
        raise KgnavError(f"MiniWorld cannot open a headless OpenGL context "
                         f"({type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}); "
                         f"on Debian: apt-get install {MESA_PACKAGES}") from None
    from miniworld import opengl

    return gl, miniworld, entity, opengl


class MiniWorldRenderer:
    """The MiniWorld scene of one house, rendered from any world pose (x, y, θ).

    ``camera``: a :class:`~kgnav.envs.spec.CameraSpec` (its size, vertical field of view,
    pitch, height and forward offset are given to MiniWorld's agent camera).
    """

    def __init__(self, house: House, camera):
        self.house, self.camera = house, camera
        gl, mw, ent, opengl = _modules()
        self._gl = gl
        renderer = self

        class World(mw.MiniWorldEnv):
            def _gen_world(self):
                renderer._build(self, ent)

        try:
            # (MiniWorld prints the multisampling it falls back to on stdout, the tables' stream)
            with contextlib.redirect_stdout(io.StringIO()), _fast_textures(gl, opengl):
                self.world = World(obs_width=camera.width, obs_height=camera.height,
                                   window_width=320, window_height=240,
                                   max_episode_steps=10**9)
        except KgnavError:
            raise
        except Exception as e:
            raise KgnavError(f"MiniWorld cannot render ({type(e).__name__}: {e}); on Debian: "
                             f"apt-get install {MESA_PACKAGES}") from None
        w = self.world
        # one light above the middle of the house (MiniWorld's default sits at its origin)
        w.light_pos = [house.width / 2, WALL_HEIGHT - 0.2, -house.depth / 2]
        a = w.agent
        a.radius = 0.18
        a.cam_fov_y = float(camera.vfov_deg)
        a.cam_pitch = float(camera.pitch_deg)
        a.cam_height = float(camera.height_m)
        a.cam_fwd_disp = float(camera.forward_m)
        w._render_static()
        _LAST[0] = w
        self._fbo = _LabelBuffer(gl, camera.width, camera.height)
        self._rooms = self._compile_label_scene()
        self.pid = os.getpid()

    # ------------------------------------------------------------------ scene
    def _build(self, world, ent) -> None:
        """MiniWorld's ``_gen_world``: the house's rooms, doors and objects."""
        h = self.house
        rooms = [world.add_rect_room(min_x=r.x0, max_x=r.x1, min_z=-r.y1, max_z=-r.y0,
                                     wall_tex=r.wall, floor_tex=r.floor,
                                     ceil_tex=CEILING_TEXTURE, wall_height=WALL_HEIGHT)
                 for r in h.rooms]
        for d in h.doors:
            a, b = rooms[d.a], rooms[d.b]
            if d.axis == 0:
                world.connect_rooms(a, b, min_x=d.lo, max_x=d.hi)
            else:
                world.connect_rooms(a, b, min_z=-d.hi, max_z=-d.lo)
        self.entities = []
        for p in h.placed:
            if p.mesh is None:
                e = ent.Box(color=p.color, size=p.height)
            else:
                e = ent.MeshEnt(mesh_name=p.mesh, height=p.height, static=True)
            world.place_entity(e, pos=np.array([p.x, 0.0, -p.y]), dir=p.dir)
            self.entities.append(e)
        x, y, t = h.nav.to_world(*map(int, np.argwhere(h.nav.grid)[0])) + (0.0,)
        world.place_agent(pos=np.array([x, 0.0, -y]), dir=t)

    # ------------------------------------------------------------------ frames
    def render(self, x: float, y: float, theta: float, labels: bool = True
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """(RGB uint8 (H, W, 3), z-depth float32 (H, W) in metres, instance ids int32 (H, W),
        0 where no object) seen from world pose (x, y, θ); ids are None unless ``labels``."""
        if os.getpid() != self.pid:
            raise KgnavError("a MiniWorld renderer cannot cross a fork: build the environment "
                             "in the process that renders it")
        w = self.world
        w.agent.pos = np.array([x, 0.0, -y])
        w.agent.dir = float(theta)
        if _LAST[0] is not w:
            w.shadow_window.switch_to()
            w._render_static()
            _LAST[0] = w
        rgb = w.render_obs().copy()
        ids, depth = self._labels(labels)
        return rgb, depth, ids

    def _compile_label_scene(self) -> int:
        """A display list of the label pass's rooms (walls, floors, ceilings: fixed).

        The objects stay drawn command by command: compiled into a list, some of their depth
        values came out up to 2e-5 m different (Mesa's display-list path), and frames must not
        depend on this optimisation."""
        gl = self._gl
        self.world.shadow_window.switch_to()
        lst = gl.glGenLists(1)
        gl.glNewList(lst, gl.GL_COMPILE)
        for room in self.world.rooms:
            room._render()
        gl.glEndList()
        return lst

    def _labels(self, labels: bool = True) -> tuple[np.ndarray | None, np.ndarray]:
        gl, w, cam = self._gl, self.world, self.camera
        w.shadow_window.switch_to()
        self._fbo.bind()
        gl.glDisable(gl.GL_MULTISAMPLE)
        gl.glDisable(gl.GL_DITHER)
        gl.glClearColor(0.0, 0.0, 0.0, 1.0)
        gl.glClearDepth(1.0)
        gl.glClear(gl.GL_COLOR_BUFFER_BIT | gl.GL_DEPTH_BUFFER_BIT)
        gl.glMatrixMode(gl.GL_PROJECTION)
        gl.glLoadIdentity()
        gl.gluPerspective(w.agent.cam_fov_y, cam.width / cam.height, _NEAR, _FAR)
        gl.glMatrixMode(gl.GL_MODELVIEW)
        gl.glLoadIdentity()
        eye, ahead = w.agent.cam_pos, w.agent.cam_pos + w.agent.cam_dir
        gl.gluLookAt(*eye, *ahead, 0.0, 1.0, 0.0)
        gl.glDisable(gl.GL_LIGHTING)
        gl.glDisable(gl.GL_TEXTURE_2D)
        gl.glEnable(gl.GL_FOG)
        gl.glFogi(gl.GL_FOG_MODE, gl.GL_EXP)
        gl.glFogf(gl.GL_FOG_DENSITY, 1e5)  # exp(-1e5 z) is 0 beyond the near plane
        gl.glFogfv(gl.GL_FOG_COLOR, (gl.GLfloat * 4)(0.0, 0.0, 0.0, 1.0))
        gl.glCallList(self._rooms)
        for k, e in enumerate(self.entities, 1):
            gl.glFogfv(gl.GL_FOG_COLOR, (gl.GLfloat * 4)((k & 255) / 255.0, (k >> 8) / 255.0,
                                                          0.0, 1.0))
            e.render()
        gl.glDisable(gl.GL_FOG)
        gl.glEnable(gl.GL_MULTISAMPLE)
        rgb, d = self._fbo.read(colour=labels)
        # window depth -> eye z (the projection's inverse)
        z = 2.0 * _NEAR * _FAR / (_FAR + _NEAR - (2.0 * d - 1.0) * (_FAR - _NEAR))
        if rgb is None:
            return None, z.astype(np.float32)
        ids = rgb[..., 0].astype(np.int32) + (rgb[..., 1].astype(np.int32) << 8)
        return ids, z.astype(np.float32)

    def top_view(self) -> tuple[np.ndarray, dict]:
        """MiniWorld's picture of the house from above and its scale (pixels per metre and
        offsets, MiniWorld's ``render_top_view(return_scale=True)``)."""
        w = self.world
        if _LAST[0] is not w:
            w.shadow_window.switch_to()
            w._render_static()
            _LAST[0] = w
        img, scale = w.render_top_view(w.vis_fb, render_agent=False, return_scale=True)
        return img.copy(), scale


class _LabelBuffer:
    """An off-screen frame buffer: 8-bit RGBA colour and 24-bit depth, read back as arrays."""

    def __init__(self, gl, width: int, height: int):
        self.gl, self.width, self.height = gl, width, height
        self.fbo = gl.GLuint(0)
        gl.glGenFramebuffers(1, ctypes.byref(self.fbo))
        gl.glBindFramebuffer(gl.GL_FRAMEBUFFER, self.fbo)
        for fmt, attach in ((gl.GL_RGBA8, gl.GL_COLOR_ATTACHMENT0),
                            (gl.GL_DEPTH_COMPONENT24, gl.GL_DEPTH_ATTACHMENT)):
            rb = gl.GLuint(0)
            gl.glGenRenderbuffers(1, ctypes.byref(rb))
            gl.glBindRenderbuffer(gl.GL_RENDERBUFFER, rb)
            gl.glRenderbufferStorage(gl.GL_RENDERBUFFER, fmt, width, height)
            gl.glFramebufferRenderbuffer(gl.GL_FRAMEBUFFER, attach, gl.GL_RENDERBUFFER, rb)
        status = gl.glCheckFramebufferStatus(gl.GL_FRAMEBUFFER)
        gl.glBindFramebuffer(gl.GL_FRAMEBUFFER, 0)
        if status != gl.GL_FRAMEBUFFER_COMPLETE:
            raise KgnavError(f"MiniWorld label buffer incomplete (OpenGL status {status:#x})")
        self._rgb = np.zeros((height, width, 3), np.uint8)
        self._depth = np.zeros((height, width), np.float32)

    def bind(self) -> None:
        gl = self.gl
        gl.glBindFramebuffer(gl.GL_FRAMEBUFFER, self.fbo)
        gl.glViewport(0, 0, self.width, self.height)

    def read(self, colour: bool = True) -> tuple[np.ndarray | None, np.ndarray]:
        """(RGB or None unless ``colour``, window depth in [0, 1]), rows top to bottom."""
        gl = self.gl
        gl.glBindFramebuffer(gl.GL_FRAMEBUFFER, self.fbo)
        gl.glPixelStorei(gl.GL_PACK_ALIGNMENT, 1)
        if colour:
            gl.glReadPixels(0, 0, self.width, self.height, gl.GL_RGB, gl.GL_UNSIGNED_BYTE,
                            self._rgb.ctypes.data_as(ctypes.POINTER(gl.GLubyte)))
        gl.glReadPixels(0, 0, self.width, self.height, gl.GL_DEPTH_COMPONENT, gl.GL_FLOAT,
                        self._depth.ctypes.data_as(ctypes.POINTER(gl.GLfloat)))
        gl.glBindFramebuffer(gl.GL_FRAMEBUFFER, 0)
        return (self._rgb[::-1].copy() if colour else None,
                self._depth[::-1].astype(np.float64))

