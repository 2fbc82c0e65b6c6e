"""The underwater image model as a fragment shader, run in the renderer's own GL context.

:class:`maptidal.envs.water.WaterModel` evaluates the model on the CPU after the colour and depth
buffers are read back. On a GPU the render itself takes about a millisecond, so that
read-back and arithmetic dominate. :class:`GLWaterPass` evaluates the same formula
where the buffers already are:

1. MuJoCo draws the camera into its (multisampled) off-screen framebuffer, as usual.
2. One blit resolves colour and depth into two textures of ours. This is the same
   resolve that ``mjr_readPixels`` does.
3. A full-screen triangle runs the shader. Per pixel it turns the reversed-Z depth into
   range along the ray, then applies attenuation, backscatter, vignetting and, if
   asked for, Gaussian noise. It writes rows top-down, so no flip is needed.
4. One ``glReadPixels`` returns the finished uint8 RGB image.

The arithmetic matches ``WaterModel.apply`` step by step, and ``tests/test_world.py``
checks that the two agree within one 8-bit level. The one exception is noise: here it
is drawn in the shader, from a counter-based hash (Box-Muller) keyed by a per-frame
seed. It has the same distribution as the CPU's draws, but is not the same sample.

The shader is GLSL 1.30 and uses the compatibility profile, which MuJoCo's fixed-function
renderer needs anyway. Where it does not compile, :func:`make_gl_water_pass` returns None and
callers fall back to the CPU model.
"""

from __future__ import annotations

import ctypes
import os
import warnings
from dataclasses import dataclass

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco
import numpy as np
from OpenGL import GL

from maptidal.envs.water import WaterParams, visibility_limit_m

_VERTEX_SHADER = """
#version 130
void main() { gl_Position = gl_Vertex; }
"""

_FRAGMENT_SHADER = """
#version 130
uniform sampler2D colour_tex;
uniform sampler2D depth_tex;
uniform vec3 beta;           // attenuation per channel, 1/m
uniform vec3 veil;           // veiling light B_inf per channel, 0..255
uniform float depth_shift;   // planar depth = depth_scale / (buffer + depth_shift)
uniform float depth_scale;
uniform float max_range;     // range beyond which nothing is visible
uniform vec4 intrinsics;     // fx, fy, cx, cy (pixels)
uniform ivec2 size;          // width, height
uniform float vignetting;
uniform float noise_sigma;   // 8-bit levels
uniform uint seed;

uint hash(uint x) {  // lowbias32 (C. Wellons), a well-mixed 32-bit integer hash
    x ^= x >> 16u; x *= 0x7feb352du; x ^= x >> 15u; x *= 0x846ca68bu; x ^= x >> 16u;
    return x;
}
float uniform01(uint x) { return (float(hash(x) >> 8u) + 0.5) * (1.0 / 16777216.0); }

void main() {
    int col = int(gl_FragCoord.x);
    int row = int(gl_FragCoord.y);            // output row, top-down once read back
    ivec2 texel = ivec2(col, size.y - 1 - row);  // GL's rows run bottom-up
    vec3 clear = texelFetch(colour_tex, texel, 0).rgb * 255.0;
    float buffer = texelFetch(depth_tex, texel, 0).r;
    float planar = depth_scale / (buffer + depth_shift);
    vec2 ray = (vec2(col, row) + 0.5 - intrinsics.zw) / intrinsics.xy;
    float range = min(planar * sqrt(1.0 + dot(ray, ray)), max_range);
    vec3 signal = veil + (clear - veil) * exp(-beta * range);   // I = B + (J - B) t
    if (vignetting > 0.0) {
        vec2 offset = (vec2(col, row) - vec2(size) * 0.5) / (vec2(size) * 0.5);
        signal *= 1.0 - vignetting * dot(offset, offset) * 0.5;
    }
    if (noise_sigma > 0.0) {
        // hashing the pixel before mixing in the seed means two frames never share a shifted
        // copy of each other's noise, as adding the seed to the pixel index would allow
        uint key = (hash(uint(row * size.x + col)) ^ seed) * 4u;
        float r1 = sqrt(-2.0 * log(uniform01(key)));
        float r2 = sqrt(-2.0 * log(uniform01(key + 2u)));
        float a1 = 6.2831853 * uniform01(key + 1u);
        float a2 = 6.2831853 * uniform01(key + 3u);
        signal += noise_sigma * vec3(r1 * cos(a1), r1 * sin(a1), r2 * cos(a2));
    }
    // round here, then aim at the middle of the level, so that either rounding rule of the
    // float-to-unorm conversion lands on the same 8-bit value
    vec3 level = clamp(floor(signal + 0.5), 0.0, 255.0);
    gl_FragColor = vec4((level + 0.25) / 255.0, 1.0);
}
"""


@dataclass(frozen=True)
class CameraGeometry:
    """What the shader needs to turn a depth-buffer value into range along the ray."""

    fx: float
    fy: float
    cx: float
    cy: float
    depth_shift: float
    depth_scale: float


def _compile(kind: int, source: str) -> int:
    shader = GL.glCreateShader(kind)
    GL.glShaderSource(shader, source)
    GL.glCompileShader(shader)
    if not GL.glGetShaderiv(shader, GL.GL_COMPILE_STATUS):
        log = GL.glGetShaderInfoLog(shader)
        GL.glDeleteShader(shader)
        raise RuntimeError(f"water shader does not compile: {log!r}")
    return shader


def _link(vertex: str, fragment: str) -> int:
    program = GL.glCreateProgram()
    shaders = [_compile(GL.GL_VERTEX_SHADER, vertex), _compile(GL.GL_FRAGMENT_SHADER, fragment)]
    for shader in shaders:
        GL.glAttachShader(program, shader)
    GL.glLinkProgram(program)
    for shader in shaders:
        GL.glDeleteShader(shader)
    if not GL.glGetProgramiv(program, GL.GL_LINK_STATUS):
        log = GL.glGetProgramInfoLog(program)
        GL.glDeleteProgram(program)
        raise RuntimeError(f"water shader does not link: {log!r}")
    return program


def _renderbuffer_format(renderbuffer: int) -> int:
    GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, renderbuffer)
    fmt = int(GL.glGetRenderbufferParameteriv(GL.GL_RENDERBUFFER, GL.GL_RENDERBUFFER_INTERNAL_FORMAT))
    GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, 0)
    return fmt


_STENCIL_FORMATS = {GL.GL_DEPTH24_STENCIL8, GL.GL_DEPTH32F_STENCIL8}
# per-fragment operations that would alter the full-screen pass
_TESTS_OFF = (GL.GL_DEPTH_TEST, GL.GL_BLEND, GL.GL_CULL_FACE, GL.GL_SCISSOR_TEST, GL.GL_STENCIL_TEST)


class GLWaterPass:
    """The water model on the GL side of one ``mujoco.Renderer`` (its context must be current).

    Create it through :func:`make_gl_water_pass`, which returns None where shaders are unavailable;
    :mod:`maptidal.envs.rendering` keeps one per renderer."""

    def __init__(self, renderer: mujoco.Renderer, geometry: CameraGeometry) -> None:
        self.renderer = renderer
        self.geometry = geometry
        self.width, self.height = renderer.width, renderer.height
        ctx = renderer._mjr_context
        renderer._gl_context.make_current()
        self._program = _link(_VERTEX_SHADER, _FRAGMENT_SHADER)
        self._uniforms = {
            name: GL.glGetUniformLocation(self._program, name)
            for name in (
                "colour_tex", "depth_tex", "beta", "veil", "depth_shift", "depth_scale", "max_range",
                "intrinsics", "size", "vignetting", "noise_sigma", "seed",
            )
        }  # fmt: skip
        # textures in exactly MuJoCo's formats, so one blit can resolve into them
        colour_format = _renderbuffer_format(ctx.offColor)
        depth_format = _renderbuffer_format(ctx.offDepthStencil)
        self._colour_tex, self._depth_tex = (int(t) for t in GL.glGenTextures(2))
        for texture, fmt in ((self._colour_tex, colour_format), (self._depth_tex, depth_format)):
            GL.glBindTexture(GL.GL_TEXTURE_2D, texture)
            GL.glTexStorage2D(GL.GL_TEXTURE_2D, 1, fmt, self.width, self.height)
            GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MIN_FILTER, GL.GL_NEAREST)
            GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MAG_FILTER, GL.GL_NEAREST)
        GL.glBindTexture(GL.GL_TEXTURE_2D, 0)
        depth_attachment = (
            GL.GL_DEPTH_STENCIL_ATTACHMENT if depth_format in _STENCIL_FORMATS else GL.GL_DEPTH_ATTACHMENT
        )
        self._resolve_fbo, self._out_fbo = (int(f) for f in GL.glGenFramebuffers(2))
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self._resolve_fbo)
        attachments = ((GL.GL_COLOR_ATTACHMENT0, self._colour_tex), (depth_attachment, self._depth_tex))
        for attachment, texture in attachments:
            GL.glFramebufferTexture2D(GL.GL_FRAMEBUFFER, attachment, GL.GL_TEXTURE_2D, texture, 0)
        self._check_complete("resolve")
        self._out_rb = int(GL.glGenRenderbuffers(1))
        GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, self._out_rb)
        GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, GL.GL_RGBA8, self.width, self.height)
        GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, 0)
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self._out_fbo)
        GL.glFramebufferRenderbuffer(
            GL.GL_FRAMEBUFFER, GL.GL_COLOR_ATTACHMENT0, GL.GL_RENDERBUFFER, self._out_rb
        )
        self._check_complete("output")
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, ctx.offFBO)
        self._water: WaterParams | None = None

    def invalidate(self) -> None:
        """Upload every uniform again before the next frame (after the geometry changed)."""
        self._water = None

    @staticmethod
    def _check_complete(which: str) -> None:
        status = GL.glCheckFramebufferStatus(GL.GL_FRAMEBUFFER)
        if status != GL.GL_FRAMEBUFFER_COMPLETE:
            raise RuntimeError(f"water pass {which} framebuffer incomplete (status {status:#x})")

    def _set_water(self, water: WaterParams) -> None:
        """Upload the uniforms that change only with the water (the program must be in use)."""
        beta, veil = water.coefficients()
        u, g = self._uniforms, self.geometry
        GL.glUniform1i(u["colour_tex"], 0)
        GL.glUniform1i(u["depth_tex"], 1)
        GL.glUniform3f(u["beta"], *(float(b) for b in beta))
        GL.glUniform3f(u["veil"], *(float(255.0 * v) for v in veil))
        GL.glUniform1f(u["depth_shift"], g.depth_shift)
        GL.glUniform1f(u["depth_scale"], g.depth_scale)
        GL.glUniform1f(u["max_range"], visibility_limit_m(beta))
        GL.glUniform4f(u["intrinsics"], g.fx, g.fy, g.cx, g.cy)
        GL.glUniform2i(u["size"], self.width, self.height)
        GL.glUniform1f(u["vignetting"], water.vignetting)
        GL.glUniform1f(u["noise_sigma"], water.noise_sigma)
        self._water = water

    def apply(
        self, water: WaterParams, seed: int = 0, with_depth: bool = False
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Turn the frame MuJoCo just drew off-screen into the underwater image.

        Returns the uint8 RGB image ``(H, W, 3)`` (rows top-down) and, with ``with_depth``, the raw
        depth buffer ``(H, W)`` float32 as GL left it (rows bottom-up, like ``render_camera``'s
        ``raw_depth``). ``seed`` keys the sensor noise of this frame."""
        ctx = self.renderer._mjr_context
        w, h = self.width, self.height
        GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, ctx.offFBO)
        GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, self._resolve_fbo)
        buffers = GL.GL_COLOR_BUFFER_BIT | GL.GL_DEPTH_BUFFER_BIT
        GL.glBlitFramebuffer(0, 0, w, h, 0, 0, w, h, buffers, GL.GL_NEAREST)
        # MuJoCo's fixed-function state is put back afterwards, so its next render is unaffected
        GL.glPushAttrib(GL.GL_ENABLE_BIT | GL.GL_VIEWPORT_BIT | buffers)
        try:
            for capability in _TESTS_OFF:
                GL.glDisable(capability)
            GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self._out_fbo)
            GL.glViewport(0, 0, w, h)
            GL.glUseProgram(self._program)
            if water is not self._water:
                self._set_water(water)
            GL.glUniform1ui(self._uniforms["seed"], seed & 0xFFFFFFFF)
            GL.glActiveTexture(GL.GL_TEXTURE1)
            GL.glBindTexture(GL.GL_TEXTURE_2D, self._depth_tex)
            GL.glActiveTexture(GL.GL_TEXTURE0)
            GL.glBindTexture(GL.GL_TEXTURE_2D, self._colour_tex)
            GL.glBegin(GL.GL_TRIANGLES)  # one triangle that covers the viewport
            GL.glVertex2f(-1.0, -1.0)
            GL.glVertex2f(3.0, -1.0)
            GL.glVertex2f(-1.0, 3.0)
            GL.glEnd()
            rgb = np.empty((h, w, 3), np.uint8)
            GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 1)
            GL.glReadPixels(0, 0, w, h, GL.GL_RGB, GL.GL_UNSIGNED_BYTE, ctypes.c_void_p(rgb.ctypes.data))
            depth = None
            if with_depth:
                depth = np.empty((h, w), np.float32)
                GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, self._resolve_fbo)
                target = ctypes.c_void_p(depth.ctypes.data)
                GL.glReadPixels(0, 0, w, h, GL.GL_DEPTH_COMPONENT, GL.GL_FLOAT, target)
        finally:
            GL.glBindTexture(GL.GL_TEXTURE_2D, 0)
            GL.glActiveTexture(GL.GL_TEXTURE1)
            GL.glBindTexture(GL.GL_TEXTURE_2D, 0)
            GL.glActiveTexture(GL.GL_TEXTURE0)
            GL.glUseProgram(0)
            GL.glPopAttrib()
            GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, ctx.offFBO)
        return rgb, depth

    def close(self) -> None:
        """Free the GL objects (the renderer's context must still exist)."""
        self.renderer._gl_context.make_current()
        GL.glDeleteFramebuffers(2, [self._resolve_fbo, self._out_fbo])
        GL.glDeleteRenderbuffers(1, [self._out_rb])
        GL.glDeleteTextures(2, [self._colour_tex, self._depth_tex])
        GL.glDeleteProgram(self._program)


# GL_RENDERER substrings of rasterisers that run on the CPU (Mesa's llvmpipe and softpipe, SwiftShader)
_SOFTWARE_RENDERERS = ("llvmpipe", "softpipe", "swiftshader", "software rasterizer")


def renderer_description(renderer: mujoco.Renderer) -> str:
    """``"GL_RENDERER, GL_VERSION"`` of ``renderer``'s context, e.g. ``"llvmpipe (LLVM 15.0.6, 256 bits),
    4.5 (Compatibility Profile) Mesa 22.3.6"``."""
    renderer._gl_context.make_current()
    names = (GL.glGetString(GL.GL_RENDERER) or b"", GL.glGetString(GL.GL_VERSION) or b"")
    return ", ".join(name.decode(errors="replace") for name in names)


def is_software_renderer(renderer: mujoco.Renderer) -> bool:
    """Whether ``renderer``'s GL context draws on the CPU (e.g. Mesa llvmpipe), not on a GPU."""
    description = renderer_description(renderer).lower()
    return any(word in description for word in _SOFTWARE_RENDERERS)


def make_gl_water_pass(renderer: mujoco.Renderer, geometry: CameraGeometry) -> GLWaterPass | None:
    """A :class:`GLWaterPass` for ``renderer``, or None (with a warning) where the GL context cannot
    run it; callers then use the CPU water model."""
    try:
        return GLWaterPass(renderer, geometry)
    except Exception as err:  # any GL failure means: use the CPU model instead
        warnings.warn(f"GL water pass unavailable, using the CPU water model: {err}", stacklevel=2)
        return None
