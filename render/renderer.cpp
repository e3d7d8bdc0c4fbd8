// Off-screen renderer: EGL (no window system) + OpenGL 3.3 core into an FBO, read back to RAM.
// Facts this relies on were measured on the project's machines (docs: stack.md §3): Mesa's
// surfaceless and device platforms both work without environment variables, llvmpipe images
// are bit-identical across platforms and thread counts, and EGL_SURFACE_TYPE must be given
// or eglChooseConfig matches no config.
#define GL_GLEXT_PROTOTYPES 1
#include <EGL/egl.h>
#include <EGL/eglext.h>
#include <GL/gl.h>
#include <GL/glext.h>

#include <cmath>
#include <cstdio>
#include <algorithm>
#include <cstring>
#include <limits>
#include <string>
#include <utility>

#include "core/error.h"
#include "core/profile.h"
#include "render/renderer.h"

namespace physketch::render {
namespace {

// ---- camera matrices (double internally: projectToPixel must agree with the GPU to far below a pixel)

Eigen::Matrix4d viewMatrixD(const Camera& camera) {
  const Vec3 forward = camera.target - camera.eye;
  if (!camera.eye.allFinite() || !camera.target.allFinite() || !camera.up.allFinite()) {
    throw RuntimeError("camera: eye, target and up must be finite");
  }
  if (forward.norm() <= 0.0) throw RuntimeError("camera: eye and target coincide");
  const Vec3 f = forward.normalized();
  const Vec3 side = f.cross(camera.up);
  if (side.norm() <= 1e-12 * camera.up.norm() || camera.up.norm() <= 0.0) {
    throw RuntimeError("camera: up vector is zero or parallel to the viewing direction");
  }
  const Vec3 s = side.normalized();
  const Vec3 u = s.cross(f);
  // gluLookAt: rows are the camera axes (x right, y up, z backwards), then translate by -eye.
  Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
  m.block<1, 3>(0, 0) = s.transpose();
  m.block<1, 3>(1, 0) = u.transpose();
  m.block<1, 3>(2, 0) = -f.transpose();
  m(0, 3) = -s.dot(camera.eye);
  m(1, 3) = -u.dot(camera.eye);
  m(2, 3) = f.dot(camera.eye);
  return m;
}

Eigen::Matrix4d projectionMatrixD(const Camera& camera, double aspect, double zNear, double zFar) {
  if (!(camera.fovYDeg > 0.0 && camera.fovYDeg < 180.0)) throw RuntimeError("camera: fovYDeg must be in (0, 180)");
  if (!(aspect > 0.0) || !std::isfinite(aspect)) throw RuntimeError("camera: aspect must be finite and > 0");
  if (!(zNear > 0.0 && zFar > zNear) || !std::isfinite(zFar)) throw RuntimeError("camera: need 0 < zNear < zFar");
  // gluPerspective: maps the view frustum to the clip cube [-1, 1]^3, w = -z_eye.
  const double halfFov = 0.5 * camera.fovYDeg * (3.14159265358979323846 / 180.0);
  const double f = 1.0 / std::tan(halfFov);
  Eigen::Matrix4d p = Eigen::Matrix4d::Zero();
  p(0, 0) = f / aspect;
  p(1, 1) = f;
  p(2, 2) = (zFar + zNear) / (zNear - zFar);
  p(2, 3) = 2.0 * zFar * zNear / (zNear - zFar);
  p(3, 2) = -1.0;
  return p;
}

// Linear -> display encoding for 8-bit output (a plain power law, not the piecewise sRGB curve).
constexpr float kGamma = 2.2f;

// ---- EGL display lifetime
//
// EGL displays are process-global: eglGetPlatformDisplay returns the same handle every time,
// eglInitialize on an initialised display is a no-op, and one eglTerminate would end it for
// every renderer still using it. So renderers never terminate the display: it lives as long
// as the process (like openvdb::initialize). This also keeps Mesa's driver loaded between
// renderers instead of re-loading it (20-85 ms each, ../shared/stack.md §3) and lets leak
// checkers see its one-time allocations as reachable rather than as leaks of an unloaded library.

std::string hex(EGLint code) {
  char buf[16];
  std::snprintf(buf, sizeof(buf), "0x%04X", static_cast<unsigned>(code));
  return buf;
}

bool hasExtension(const char* list, const char* name) {
  if (!list) return false;
  const std::size_t n = std::strlen(name);
  for (const char* p = std::strstr(list, name); p; p = std::strstr(p + 1, name)) {
    const bool startOk = p == list || p[-1] == ' ';
    const bool endOk = p[n] == '\0' || p[n] == ' ';
    if (startOk && endOk) return true;
  }
  return false;
}

// Initialises one candidate display; on failure appends why to `log` and returns EGL_NO_DISPLAY.
EGLDisplay tryInitialize(EGLDisplay d, const std::string& label, std::string& log) {
  if (d == EGL_NO_DISPLAY) {
    log += "; " + label + ": no display (" + hex(eglGetError()) + ")";
    return EGL_NO_DISPLAY;
  }
  EGLint major = 0, minor = 0;
  if (!eglInitialize(d, &major, &minor)) {
    log += "; " + label + ": eglInitialize failed (" + hex(eglGetError()) + ")";
    return EGL_NO_DISPLAY;
  }
  return d;
}

struct AcquiredDisplay {
  EGLDisplay display = EGL_NO_DISPLAY;
  std::string description;  // which platform or device, for OffscreenRenderer::deviceDescription
};

// Describes a non-software EGL device: its DRM device file when it has one (EGL_EXT_device_drm).
std::string describeHardwareDevice(EGLDeviceEXT device, PFNEGLQUERYDEVICESTRINGEXTPROC queryDeviceString) {
  const char* ext = queryDeviceString(device, EGL_EXTENSIONS);
  if (hasExtension(ext, "EGL_EXT_device_drm")) {
    if (const char* file = queryDeviceString(device, EGL_DRM_DEVICE_FILE_EXT)) return std::string("hardware, ") + file;
  }
  return "hardware";
}

// Tries the displays in displayOrder's order (documented at OffscreenRenderer in renderer.h).
// Why this order for GlDevice::Cpu:
//  1. the software device first: on a machine with a GPU the surfaceless platform may pick the
//     GPU, whose rasteriser gives different pixels; the software device keeps images identical
//     on every machine with the same Mesa.
//  2. Mesa's surfaceless platform: Mesa loads the hardware driver of a DRM render node when one
//     exists and has a Mesa driver, else llvmpipe (on the project's machines: llvmpipe, no
//     render node).
//  3. any other EGL device, in enumeration order: a GPU (e.g. NVIDIA's EGL via libglvnd).
// Plain eglGetDisplay(EGL_DEFAULT_DISPLAY) is not tried: without a display server it fails
// unless EGL_PLATFORM=surfaceless is set in the environment.
AcquiredDisplay acquireDisplay(GlDevice wanted) {
  std::string log;
  const char* clientExt = eglQueryString(EGL_NO_DISPLAY, EGL_EXTENSIONS);
  auto getPlatformDisplay =
      reinterpret_cast<PFNEGLGETPLATFORMDISPLAYEXTPROC>(eglGetProcAddress("eglGetPlatformDisplayEXT"));
  if (!getPlatformDisplay || !hasExtension(clientExt, "EGL_EXT_platform_base")) {
    throw RuntimeError("EGL: eglGetPlatformDisplayEXT is unavailable (client extensions: " +
                       std::string(clientExt ? clientExt : "none") +
                       "); install Mesa's libegl-mesa0, or a GPU's EGL driver for --gl-device gpu");
  }

  std::vector<EGLDeviceEXT> devices;
  std::vector<bool> isSoftware;
  auto queryDevices = reinterpret_cast<PFNEGLQUERYDEVICESEXTPROC>(eglGetProcAddress("eglQueryDevicesEXT"));
  auto queryDeviceString =
      reinterpret_cast<PFNEGLQUERYDEVICESTRINGEXTPROC>(eglGetProcAddress("eglQueryDeviceStringEXT"));
  if (queryDevices && queryDeviceString && hasExtension(clientExt, "EGL_EXT_platform_device")) {
    EGLDeviceEXT listed[16];
    EGLint count = 0;
    if (queryDevices(16, listed, &count)) {
      for (EGLint i = 0; i < count; ++i) {
        devices.push_back(listed[i]);
        isSoftware.push_back(hasExtension(queryDeviceString(listed[i], EGL_EXTENSIONS), "EGL_MESA_device_software"));
        log += "; EGL device " + std::to_string(i) + (isSoftware.back() ? ": software" : ": hardware");
      }
      if (count == 0) log += "; EGL lists no devices";
    } else {
      log += "; eglQueryDevicesEXT failed (" + hex(eglGetError()) + ")";
    }
  } else {
    log += "; no EGL device enumeration";
  }
  const bool hasSurfaceless = hasExtension(clientExt, "EGL_MESA_platform_surfaceless");

  for (const DisplayCandidate& c : displayOrder(isSoftware, hasSurfaceless, wanted)) {
    if (c.kind == DisplayCandidate::Kind::Surfaceless) {
      const std::string label = "EGL Mesa surfaceless platform";
      EGLDisplay d = tryInitialize(getPlatformDisplay(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, nullptr),
                                   label, log);
      if (d != EGL_NO_DISPLAY) return {d, label + " (no software device found; Mesa chose the driver)"};
      continue;
    }
    const EGLDeviceEXT device = devices[static_cast<std::size_t>(c.deviceIndex)];
    const std::string label = "EGL device " + std::to_string(c.deviceIndex);
    EGLDisplay d = tryInitialize(getPlatformDisplay(EGL_PLATFORM_DEVICE_EXT, device, nullptr), label, log);
    if (d != EGL_NO_DISPLAY) {
      return {d, label + (isSoftware[static_cast<std::size_t>(c.deviceIndex)]
                              ? std::string(" (EGL_MESA_device_software)")
                              : " (" + describeHardwareDevice(device, queryDeviceString) + ")")};
    }
  }
  if (wanted == GlDevice::Gpu) {
    throw RuntimeError("EGL: no hardware (GPU) EGL device could be used, and --gl-device gpu asks for one "
                       "(without it, the default 'cpu' draws with Mesa's llvmpipe)" + log);
  }
  if (!hasSurfaceless) log += "; no EGL_MESA_platform_surfaceless";
  throw RuntimeError("EGL: no usable display" + log);
}

// ---- shaders

const char* const kVertexShader = R"(#version 330 core
layout(location = 0) in vec3 aPosition;  // model space (m)
layout(location = 1) in vec3 aNormal;    // model space, unit
uniform mat4 uModel;
uniform mat3 uNormalMatrix;              // inverse transpose of uModel's 3x3 block
uniform mat4 uView;
uniform mat4 uProj;
uniform mat4 uLightViewProj;             // world -> the shadow map's clip space
out vec3 vWorldPos;
out vec3 vNormal;
out vec4 vLightPos;
void main() {
  vec4 world = uModel * vec4(aPosition, 1.0);
  vWorldPos = world.xyz;
  vNormal = uNormalMatrix * aNormal;
  vLightPos = uLightViewProj * world;
  gl_Position = uProj * (uView * world);
}
)";

// Normalised Blinn-Phong (see kDefaultRoughness in renderer.h), one directional light plus
// ambient, in linear RGB; the light's share is scaled by the shadow map's visibility; the
// result is gamma-encoded on output.
const char* const kFragmentShader = R"(#version 330 core
in vec3 vWorldPos;
in vec3 vNormal;
in vec4 vLightPos;
uniform vec3 uColor;          // linear RGB
uniform float uRoughness;     // [0, 1]
uniform vec3 uEye;            // camera position (m)
uniform vec3 uLightDir;       // unit, pointing from the surface towards the light
uniform float uCheckerCell;   // > 0: checkerboard in x/z with this cell size (m)
uniform float uInvGamma;
uniform int uShadows;         // 1: look up uShadowMap
uniform sampler2DShadow uShadowMap;
uniform float uShadowBias;    // in the shadow map's [0, 1] depth
out vec4 fragColor;

// Share of the light that reaches this fragment: percentage-closer filtering over a tent 3
// texels wide, as four bilinearly filtered comparisons half a texel off the centre (each covers
// 2 x 2 texels; at a texel centre the weights are 1 2 1 x 1 2 1 / 16), so shadow edges are soft
// over about 2 texels. The nine comparisons on whole-texel offsets used before (a filter 4
// texels wide) cost llvmpipe about 15 ms more per 1280 x 720 frame at 4x MSAA, where it shades
// every sample (bench_render's draw, 105 -> 90 ms); the jelly example's frame then differs in
// 0.7 % of its pixels, at shadow edges. Outside the map nothing casts a shadow; behind its far
// plane (below every caster) the depth is clamped to it.
float visibility() {
  if (uShadows == 0) return 1.0;
  vec3 p = vLightPos.xyz / vLightPos.w * 0.5 + 0.5;
  if (p.x < 0.0 || p.x > 1.0 || p.y < 0.0 || p.y > 1.0) return 1.0;
  float z = clamp(p.z, 0.0, 1.0) - uShadowBias;
  vec2 o = 0.5 / vec2(textureSize(uShadowMap, 0));
  float lit = texture(uShadowMap, vec3(p.xy + vec2(-o.x, -o.y), z)) +
              texture(uShadowMap, vec3(p.xy + vec2(o.x, -o.y), z)) +
              texture(uShadowMap, vec3(p.xy + vec2(-o.x, o.y), z)) +
              texture(uShadowMap, vec3(p.xy + vec2(o.x, o.y), z));
  return lit / 4.0;
}

void main() {
  vec3 n = normalize(vNormal);
  // Back faces (visible only through open meshes or from under the ground) are lit as the
  // front face seen from this side.
  if (!gl_FrontFacing) n = -n;
  vec3 base = uColor;
  if (uCheckerCell > 0.0) {
    vec2 cell = floor(vWorldPos.xz / uCheckerCell);
    if (mod(cell.x + cell.y, 2.0) >= 1.0) base *= 0.8;
  }
  vec3 v = normalize(uEye - vWorldPos);
  float diffuse = max(dot(n, uLightDir), 0.0);
  vec3 h = normalize(uLightDir + v);
  float a = max(uRoughness, 0.1);
  a = a * a;
  float shininess = 2.0 / (a * a) - 2.0;
  // F0 = 0.04: the reflectance of a dielectric at normal incidence (index of refraction 1.5).
  float specular = diffuse > 0.0 ? 0.04 * (shininess + 8.0) / 8.0 * pow(max(dot(n, h), 0.0), shininess) * diffuse : 0.0;
  float light = visibility();
  vec3 linear = base * (0.25 + 0.75 * diffuse * light) + vec3(specular * light);
  fragColor = vec4(pow(clamp(linear, 0.0, 1.0), vec3(uInvGamma)), 1.0);
}
)";

// Depth only, from the light.
const char* const kShadowVertexShader = R"(#version 330 core
layout(location = 0) in vec3 aPosition;
uniform mat4 uLightMvp;
void main() { gl_Position = uLightMvp * vec4(aPosition, 1.0); }
)";
const char* const kShadowFragmentShader = R"(#version 330 core
void main() {}
)";

// One triangle over the whole viewport (no vertex buffer: positions from gl_VertexID), coloured
// by the height of the pixel centre in the viewport.
const char* const kBackgroundVertexShader = R"(#version 330 core
void main() {
  vec2 p = vec2(gl_VertexID == 1 ? 3.0 : -1.0, gl_VertexID == 2 ? 3.0 : -1.0);
  gl_Position = vec4(p, 1.0, 1.0);
}
)";
const char* const kBackgroundFragmentShader = R"(#version 330 core
uniform vec3 uTop;       // linear RGB at the top edge
uniform vec3 uBottom;    // linear RGB at the bottom edge
uniform float uHeight;   // viewport height (pixels)
uniform float uInvGamma;
out vec4 fragColor;
void main() {
  vec3 linear = mix(uBottom, uTop, gl_FragCoord.y / uHeight);
  fragColor = vec4(pow(clamp(linear, 0.0, 1.0), vec3(uInvGamma)), 1.0);
}
)";

// Gaussian splats (OffscreenRenderer::drawSplats): one instanced quad per splat, sized to 3
// standard deviations of its projected Gaussian; the fragment shader evaluates the Gaussian.
// What the splat shaders (drawn and shadow) share, pasted into their sources: the quad of a
// projected Gaussian of 2-D covariance C (pixels^2; + 0.3 px^2 of filter), its conic (the
// inverse covariance: xx, xy, yy) and this vertex's corner offset; false when degenerate.
#define PHYSKETCH_SPLAT_QUAD_GLSL \
  "bool splatQuad(mat3 C, out vec3 conic, out vec2 offset) {\n" \
  "  float a = C[0][0] + 0.3, b = C[0][1], c = C[1][1] + 0.3;\n" \
  "  float det = a * c - b * b;\n" \
  "  if (!(det > 0.0)) return false;\n" \
  "  conic = vec3(c, -b, a) / det;\n" \
  "  float mid = 0.5 * (a + c);\n" \
  "  float radius = ceil(3.0 * sqrt(mid + sqrt(max(0.0, mid * mid - det))));\n" \
  "  vec2 corner = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1)) * 2.0 - 1.0;\n" \
  "  offset = corner * radius;\n" \
  "  return true;\n" \
  "}\n"
// The Gaussian's exponent at a pixel offset from its centre.
#define PHYSKETCH_SPLAT_POWER_GLSL \
  "float splatPower(vec2 o, vec3 conic) {\n" \
  "  return -0.5 * (conic.x * o.x * o.x + conic.z * o.y * o.y) - conic.y * o.x * o.y;\n" \
  "}\n"
const char* const kSplatVertexShader = R"(#version 330 core
layout(location = 0) in vec3 aCentre;
layout(location = 1) in vec3 aCovA;    // covariance xx, xy, xz (m^2)
layout(location = 2) in vec3 aCovB;    // yy, yz, zz
layout(location = 3) in vec3 aColor;   // linear RGB
layout(location = 4) in float aOpacity;
layout(location = 5) in vec3 aNormal;  // unit, or zero: unlit
uniform vec3 uLightDir;                // unit, towards the light
uniform mat4 uView;
uniform mat4 uProj;
uniform vec2 uViewport;                // pixels
uniform float uInvGamma;
out vec2 vOffset;                      // from the projected centre, pixels (y up)
// Constant over a splat: flat (not interpolated), and the colour gamma-encoded here once per
// vertex rather than per fragment (three pow a fragment were much of llvmpipe's splat cost).
flat out vec3 vConic;                  // the inverse of Sigma2: (xx, xy, yy)
flat out vec3 vColor;                  // gamma-encoded
flat out float vOpacity;
)" PHYSKETCH_SPLAT_QUAD_GLSL R"(void main() {
  vec4 t = uView * vec4(aCentre, 1.0);
  float z = -t.z;                      // depth in front of the eye
  vOffset = vec2(0.0);
  vConic = vec3(0.0);
  // The mesh shader's ambient + diffuse, once per splat.
  vec3 lit = dot(aNormal, aNormal) > 0.25 ? aColor * (0.25 + 0.75 * max(dot(aNormal, uLightDir), 0.0)) : aColor;
  vColor = pow(clamp(lit, 0.0, 1.0), vec3(uInvGamma));
  vOpacity = 0.0;
  if (z <= 0.0) {                      // behind the eye: a degenerate quad, drawn nowhere
    gl_Position = vec4(2.0, 2.0, 2.0, 1.0);
    return;
  }
  vec4 clip = uProj * t;
  float fx = uProj[0][0] * 0.5 * uViewport.x, fy = uProj[1][1] * 0.5 * uViewport.y;
  // d(pixel) / d(view position) at t (columns: x, y, z), the perspective divide linearised.
  mat3 J = mat3(fx / z, 0.0, 0.0, 0.0, fy / z, 0.0, fx * t.x / (z * z), fy * t.y / (z * z), 0.0);
  mat3 T = J * mat3(uView);
  mat3 S = mat3(aCovA.x, aCovA.y, aCovA.z, aCovA.y, aCovB.x, aCovB.y, aCovA.z, aCovB.y, aCovB.z);
  if (!splatQuad(T * S * transpose(T), vConic, vOffset)) {
    gl_Position = vec4(2.0, 2.0, 2.0, 1.0);
    return;
  }
  vOpacity = aOpacity;
  gl_Position = clip + vec4(vOffset * 2.0 / uViewport * clip.w, 0.0, 0.0);
}
)";
const char* const kSplatFragmentShader = R"(#version 330 core
in vec2 vOffset;
flat in vec3 vConic;
flat in vec3 vColor;
flat in float vOpacity;
out vec4 fragColor;
)" PHYSKETCH_SPLAT_POWER_GLSL R"(void main() {
  float alpha = min(0.99, vOpacity * exp(splatPower(vOffset, vConic)));
  if (alpha < 1.0 / 255.0) discard;
  fragColor = vec4(vColor * alpha, alpha);  // premultiplied
}
)";

// Splats in the shadow pass: the same projected Gaussian, in the light's orthographic clip space
// (pixel = (clip.xy + 1) / 2 * map size, an affine map, so its Jacobian is exact); a splat
// occludes the light where its opacity-weighted Gaussian reaches 1/2, and writes its centre's
// depth there.
const char* const kSplatShadowVertexShader = R"(#version 330 core
layout(location = 0) in vec3 aCentre;
layout(location = 1) in vec3 aCovA;
layout(location = 2) in vec3 aCovB;
layout(location = 4) in float aOpacity;
uniform mat4 uLightViewProj;
uniform float uMapSize;                // texels
out vec2 vOffset;
flat out vec3 vConic;
flat out float vOpacity;
)" PHYSKETCH_SPLAT_QUAD_GLSL R"(void main() {
  vec4 clip = uLightViewProj * vec4(aCentre, 1.0);
  float s = 0.5 * uMapSize;
  mat3 T = mat3(s, 0.0, 0.0, 0.0, s, 0.0, 0.0, 0.0, 0.0) * mat3(uLightViewProj);
  mat3 S = mat3(aCovA.x, aCovA.y, aCovA.z, aCovA.y, aCovB.x, aCovB.y, aCovA.z, aCovB.y, aCovB.z);
  vOffset = vec2(0.0);
  vConic = vec3(0.0);
  vOpacity = 0.0;
  if (!splatQuad(T * S * transpose(T), vConic, vOffset)) {
    gl_Position = vec4(2.0, 2.0, 2.0, 1.0);
    return;
  }
  vOpacity = aOpacity;
  gl_Position = clip + vec4(vOffset * 2.0 / uMapSize * clip.w, 0.0, 0.0);
}
)";
const char* const kSplatShadowFragmentShader = R"(#version 330 core
in vec2 vOffset;
flat in vec3 vConic;
flat in float vOpacity;
)" PHYSKETCH_SPLAT_POWER_GLSL R"(void main() {
  if (vOpacity * exp(splatPower(vOffset, vConic)) < 0.5) discard;
}
)";

GLuint compileShader(GLenum type, const char* source) {
  GLuint s = glCreateShader(type);
  glShaderSource(s, 1, &source, nullptr);
  glCompileShader(s);
  GLint ok = GL_FALSE;
  glGetShaderiv(s, GL_COMPILE_STATUS, &ok);
  if (!ok) {
    char info[2048] = {0};
    glGetShaderInfoLog(s, sizeof(info), nullptr, info);
    glDeleteShader(s);
    throw RuntimeError(std::string("GL: ") + (type == GL_VERTEX_SHADER ? "vertex" : "fragment") +
                       " shader failed to compile: " + info);
  }
  return s;
}

struct GpuMesh {
  GLuint vao = 0, vbo = 0, ebo = 0;
  GLsizei indexCount = 0;
  bool live = false;  // false once freed (names are then 0)
  Eigen::AlignedBox3f bounds;  // of the positions, model space: fits the shadow map to what casts
};

// Compiles and links a program; throws with the GL info log.
GLuint linkProgram(const char* vertexSource, const char* fragmentSource) {
  const GLuint vs = compileShader(GL_VERTEX_SHADER, vertexSource);
  GLuint fs = 0;
  try {
    fs = compileShader(GL_FRAGMENT_SHADER, fragmentSource);
  } catch (...) {
    glDeleteShader(vs);
    throw;
  }
  const GLuint program = glCreateProgram();
  glAttachShader(program, vs);
  glAttachShader(program, fs);
  glLinkProgram(program);
  glDeleteShader(vs);  // flagged; freed with the program
  glDeleteShader(fs);
  GLint ok = GL_FALSE;
  glGetProgramiv(program, GL_LINK_STATUS, &ok);
  if (!ok) {
    char info[2048] = {0};
    glGetProgramInfoLog(program, sizeof(info), nullptr, info);
    glDeleteProgram(program);
    throw RuntimeError(std::string("GL: shader program failed to link: ") + info);
  }
  return program;
}

// One recorded draw call of the current frame (run in endFrame).
struct DrawCall {
  int handle;           // -1: the ground quad
  Mat4f model;
  Color color;
  float roughness;
  float checkerCell;    // > 0: the ground's checkerboard
  bool isMesh;          // counted in meshSamples, casts a shadow
};

// Light view-projection fitted around `box` (world): an orthographic box along -light, a
// little larger than the casters (2% plus the 1-texel reach of the 3 x 3 filter) so their
// silhouettes never touch the map's edge. Depth covers the casters only: receivers beyond
// them are clamped to the far plane in the shader (in shadow where a caster covers them).
Eigen::Matrix4d lightViewProjection(const Eigen::AlignedBox3d& box, int mapSize) {
  const Vec3 l = lightDirection();
  const Vec3 up = std::abs(l.y()) > 0.99 ? Vec3::UnitZ() : Vec3::UnitY();
  const Vec3 f = -l;  // the light looks along -l
  const Vec3 s = f.cross(up).normalized();
  const Vec3 u = s.cross(f);
  Eigen::Matrix4d view = Eigen::Matrix4d::Identity();
  view.block<1, 3>(0, 0) = s.transpose();
  view.block<1, 3>(1, 0) = u.transpose();
  view.block<1, 3>(2, 0) = -f.transpose();
  Eigen::AlignedBox3d lightBox;
  for (int c = 0; c < 8; ++c)
    lightBox.extend((view * box.corner(static_cast<Eigen::AlignedBox3d::CornerType>(c)).homogeneous()).head<3>());
  const Vec3 size = lightBox.sizes();
  const double pad = 0.02 * std::max(size.x(), size.y()) + 1e-6;
  Vec3 lo = lightBox.min() - Vec3(pad, pad, pad), hi = lightBox.max() + Vec3(pad, pad, pad);
  const double texel = std::max(hi.x() - lo.x(), hi.y() - lo.y()) / mapSize;
  lo.head<2>() -= Eigen::Vector2d::Constant(2.0 * texel);
  hi.head<2>() += Eigen::Vector2d::Constant(2.0 * texel);
  // glOrtho(l, r, b, t, n, f) with eye-space z in [-far, -near]: near = -hi.z, far = -lo.z.
  const double n = -hi.z(), fr = -lo.z();
  Eigen::Matrix4d ortho = Eigen::Matrix4d::Identity();
  ortho(0, 0) = 2.0 / (hi.x() - lo.x());
  ortho(1, 1) = 2.0 / (hi.y() - lo.y());
  ortho(2, 2) = -2.0 / (fr - n);
  ortho(0, 3) = -(hi.x() + lo.x()) / (hi.x() - lo.x());
  ortho(1, 3) = -(hi.y() + lo.y()) / (hi.y() - lo.y());
  ortho(2, 3) = -(fr + n) / (fr - n);
  return ortho * view;
}

// Mesh checks shared by upload and update: throws before any GL object is touched.
void validateMesh(const TriangleMesh& mesh, const char* who) {
  const std::size_t n = mesh.positions.size();
  if (mesh.normals.size() != n) {
    throw RuntimeError(std::string(who) + ": " + std::to_string(mesh.normals.size()) + " normals for " +
                       std::to_string(n) + " positions");
  }
  if (mesh.indices.size() % 3 != 0) throw RuntimeError(std::string(who) + ": index count is not a multiple of 3");
  for (std::uint32_t i : mesh.indices) {
    if (i >= n) throw RuntimeError(std::string(who) + ": index " + std::to_string(i) + " out of range");
  }
}

// Interleaved position + normal, 6 floats per vertex.
std::vector<float> interleave(const TriangleMesh& mesh) {
  const std::size_t n = mesh.positions.size();
  std::vector<float> vertices(6 * n);
  for (std::size_t i = 0; i < n; ++i) {
    for (int c = 0; c < 3; ++c) {
      vertices[6 * i + c] = mesh.positions[i][c];
      vertices[6 * i + 3 + c] = mesh.normals[i][c];
    }
  }
  return vertices;
}

}  // namespace

GlDevice parseGlDevice(const std::string& name) {
  if (name == "cpu") return GlDevice::Cpu;
  if (name == "gpu") return GlDevice::Gpu;
  throw RuntimeError("GL device '" + name + "': expected cpu or gpu");
}

const char* glDeviceName(GlDevice device) { return device == GlDevice::Gpu ? "gpu" : "cpu"; }

std::vector<DisplayCandidate> displayOrder(const std::vector<bool>& deviceIsSoftware, bool hasSurfaceless,
                                           GlDevice device) {
  std::vector<DisplayCandidate> order;
  const int n = static_cast<int>(deviceIsSoftware.size());
  if (device == GlDevice::Cpu) {
    for (int i = 0; i < n; ++i) {
      if (deviceIsSoftware[static_cast<std::size_t>(i)]) order.push_back({DisplayCandidate::Kind::Device, i});
    }
    if (hasSurfaceless) order.push_back({DisplayCandidate::Kind::Surfaceless, -1});
  }
  for (int i = 0; i < n; ++i) {
    if (!deviceIsSoftware[static_cast<std::size_t>(i)]) order.push_back({DisplayCandidate::Kind::Device, i});
  }
  return order;
}

Mat4f viewMatrix(const Camera& camera) { return viewMatrixD(camera).cast<float>(); }

Mat4f projectionMatrix(const Camera& camera, double aspect, double zNear, double zFar) {
  return projectionMatrixD(camera, aspect, zNear, zFar).cast<float>();
}

bool projectToPixel(const Camera& camera, int width, int height, const Vec3& world, Eigen::Vector2d& pixel) {
  if (width <= 0 || height <= 0) throw RuntimeError("projectToPixel: image size must be positive");
  // Near and far only change clip z, never x, y or w, so any valid pair gives the same pixel.
  const ClipRange anyValid;
  const Eigen::Vector4d clip = projectionMatrixD(camera, double(width) / double(height), anyValid.zNear,
                                                 anyValid.zFar) *
                               (viewMatrixD(camera) * world.homogeneous());
  if (!(clip.w() > 0.0)) return false;  // on or behind the camera plane
  const double ndcX = clip.x() / clip.w(), ndcY = clip.y() / clip.w();
  pixel.x() = (ndcX * 0.5 + 0.5) * width;
  pixel.y() = (1.0 - (ndcY * 0.5 + 0.5)) * height;  // row 0 is the top of the image
  return true;
}

ClipRange clipRangeFor(const Camera& camera, const Eigen::AlignedBox3d& drawable) {
  if (drawable.isEmpty() || !drawable.min().allFinite() || !drawable.max().allFinite()) {
    throw RuntimeError("clipRangeFor: the drawable box must be non-empty and finite");
  }
  // Eye depth of a point = -z in eye space (the camera looks down -z); the view matrix also
  // rejects a degenerate camera.
  const Eigen::Matrix4d view = viewMatrixD(camera);
  double dMin = std::numeric_limits<double>::infinity(), dMax = -dMin;
  for (int c = 0; c < 8; ++c) {
    const Vec3 corner = drawable.corner(static_cast<Eigen::AlignedBox3d::CornerType>(c));
    const double depth = -view.row(2).dot(corner.homogeneous());
    dMin = std::min(dMin, depth);
    dMax = std::max(dMax, depth);
  }
  if (!(dMax > 0.0)) {
    // All behind the camera: nothing can be seen. A range on the scene's scale keeps the
    // projection well conditioned.
    const double far = std::max((drawable.center() - camera.eye).norm() + drawable.diagonal().norm(), 1e-3);
    return {far / kMaxDepthRatio, far};
  }
  ClipRange r;
  r.zFar = dMax * (1.0 + kClipMargin);
  // dMin <= 0 (the camera inside the box or beside it) leaves only the precision bound.
  r.zNear = std::max(dMin / (1.0 + kClipMargin), r.zFar / kMaxDepthRatio);
  return r;
}

struct OffscreenRenderer::Impl {
  int width = 0, height = 0;
  Looks looks;
  EGLDisplay display = EGL_NO_DISPLAY;
  EGLContext context = EGL_NO_CONTEXT;
  // fbo: where the frame is drawn (multisampled when looks.samples > 1); resolveFbo: one
  // sample per pixel, read back (0 when fbo itself has one sample).
  GLuint fbo = 0, colorRb = 0, depthRb = 0, resolveFbo = 0, resolveRb = 0;
  GLuint shadowFbo = 0, shadowTex = 0;
  GLuint program = 0, shadowProgram = 0, backgroundProgram = 0, emptyVao = 0;
  GLint uModel = -1, uNormalMatrix = -1, uView = -1, uProj = -1, uColor = -1, uRoughness = -1, uEye = -1,
        uLightDir = -1, uCheckerCell = -1, uInvGamma = -1, uLightViewProj = -1, uShadows = -1, uShadowMap = -1,
        uShadowBias = -1;
  GLint uLightMvp = -1;
  GLint uTop = -1, uBottom = -1, uHeight = -1, uBgInvGamma = -1;
  GLuint splatProgram = 0, splatVao = 0, splatVbo = 0;
  GLint uSplatView = -1, uSplatProj = -1, uSplatViewport = -1, uSplatInvGamma = -1, uSplatLightDir = -1;
  GLuint splatShadowProgram = 0;
  GLint uSplatShadowLvp = -1, uSplatShadowMapSize = -1;
  static constexpr int kSplatFloats = 16;
  std::vector<Splat> splats;  // the frame's, in call order
  std::vector<GpuMesh> meshes;  // indexed by handle; freed slots stay (handles are never reused)
  GpuMesh ground;  // unit square [-1, 1]^2 in x/z at y = 0, normal +y
  // One GL_SAMPLES_PASSED query per drawMesh call of the current frame, read in endFrame
  // (reading each right after its draw would wait for the rasteriser every time).
  std::vector<GLuint> queries;
  std::size_t queriesUsed = 0;
  std::string description;  // deviceDescription()
  bool inFrame = false;
  // The frame being recorded.
  Mat4f view = Mat4f::Identity(), proj = Mat4f::Identity();
  Vec3f eye = Vec3f::Zero();
  Background background;
  std::vector<DrawCall> calls;

  GlDevice device = GlDevice::Cpu;  // which display to ask for (createContext)

  Impl(int w, int h, const Looks& l, GlDevice d) : width(w), height(h), looks(l), device(d) {}
  ~Impl() { destroy(); }

  void createContext();
  void createFramebuffer();
  void createShadowMap();
  void createProgram();
  void makeCurrent() const;
  GpuMesh upload(const TriangleMesh& mesh) const;
  void fill(GpuMesh& g, const TriangleMesh& mesh) const;
  GpuMesh& liveMesh(int handle, const char* who);
  const GpuMesh& meshOf(const DrawCall& c) { return c.handle < 0 ? ground : liveMesh(c.handle, "endFrame"); }
  bool renderShadowMap(Eigen::Matrix4d& lightViewProj);
  void drawBackground();
  void draw(const GpuMesh& m, const DrawCall& c, bool countSamples);
  void drawSplats();
  // Fills the splat buffer with the frame's splats, back to front (the order drawSplats blends
  // them in; the shadow pass draws the same buffer), once per frame.
  void uploadSplats();
  bool splatsUploaded = false;
  std::uint64_t collectMeshSamples() const;
  void destroy();
  void checkGl(const char* where) const {
    const GLenum e = glGetError();
    if (e != GL_NO_ERROR) throw RuntimeError(std::string("GL error ") + hex(static_cast<EGLint>(e)) + " in " + where);
  }
};

void OffscreenRenderer::Impl::createContext() {
  AcquiredDisplay acquired = acquireDisplay(device);
  display = acquired.display;
  description = std::move(acquired.description);
  if (!eglBindAPI(EGL_OPENGL_API)) throw RuntimeError("EGL: desktop OpenGL API unavailable (" + hex(eglGetError()) + ")");

  // Only an FBO is rendered to, so the config's surface type is irrelevant, but the default
  // (EGL_WINDOW_BIT) matches nothing on these displays.
  const EGLint configAttribs[] = {EGL_SURFACE_TYPE, EGL_PBUFFER_BIT, EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT,
                                  EGL_RED_SIZE, 8, EGL_GREEN_SIZE, 8, EGL_BLUE_SIZE, 8, EGL_ALPHA_SIZE, 8,
                                  EGL_DEPTH_SIZE, 24, EGL_NONE};
  EGLConfig configs[64];
  EGLint count = 0;
  if (!eglChooseConfig(display, configAttribs, configs, 64, &count) || count == 0) {
    throw RuntimeError("EGL: no RGBA8/depth24 OpenGL config (" + hex(eglGetError()) + ")");
  }
  // EGL sorts deeper colour first (Mesa lists 10/10/10/2 before 8/8/8/8): take an exact match.
  EGLConfig config = configs[0];
  for (EGLint i = 0; i < count; ++i) {
    EGLint r = 0, g = 0, b = 0, a = 0;
    eglGetConfigAttrib(display, configs[i], EGL_RED_SIZE, &r);
    eglGetConfigAttrib(display, configs[i], EGL_GREEN_SIZE, &g);
    eglGetConfigAttrib(display, configs[i], EGL_BLUE_SIZE, &b);
    eglGetConfigAttrib(display, configs[i], EGL_ALPHA_SIZE, &a);
    if (r == 8 && g == 8 && b == 8 && a == 8) {
      config = configs[i];
      break;
    }
  }
  const EGLint contextAttribs[] = {EGL_CONTEXT_MAJOR_VERSION, 3, EGL_CONTEXT_MINOR_VERSION, 3,
                                   EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT, EGL_NONE};
  context = eglCreateContext(display, config, EGL_NO_CONTEXT, contextAttribs);
  if (context == EGL_NO_CONTEXT) {
    throw RuntimeError("EGL: cannot create an OpenGL 3.3 core context (" + hex(eglGetError()) + ")");
  }
  // No surface at all (EGL_KHR_surfaceless_context): everything is drawn into our FBO.
  if (!eglMakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, context)) {
    throw RuntimeError("EGL: eglMakeCurrent without a surface failed (" + hex(eglGetError()) + ")");
  }
  const GLubyte* renderer = glGetString(GL_RENDERER);
  description += " | GL_RENDERER " + std::string(renderer ? reinterpret_cast<const char*>(renderer) : "(unknown)");
}

void OffscreenRenderer::Impl::makeCurrent() const {
  // The bound API is per thread, and eglGetCurrentContext answers for the bound API only.
  eglBindAPI(EGL_OPENGL_API);
  if (eglGetCurrentContext() == context) return;
  if (!eglMakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, context)) {
    throw RuntimeError("EGL: eglMakeCurrent failed (" + hex(eglGetError()) + ")");
  }
}

void OffscreenRenderer::Impl::createFramebuffer() {
  GLint maxSize = 0, maxSamples = 0;
  glGetIntegerv(GL_MAX_RENDERBUFFER_SIZE, &maxSize);
  glGetIntegerv(GL_MAX_SAMPLES, &maxSamples);
  if (width > maxSize || height > maxSize) {
    throw RuntimeError("GL: image " + std::to_string(width) + "x" + std::to_string(height) +
                       " exceeds the renderbuffer limit " + std::to_string(maxSize));
  }
  const int samples = looks.samples;
  if (samples < 1 || (samples & (samples - 1)) != 0 || samples > std::max(maxSamples, 1)) {
    throw RuntimeError("GL: " + std::to_string(samples) + " samples per pixel: need 1 or a power of two up to " +
                       std::to_string(maxSamples) + " (GL_MAX_SAMPLES)");
  }
  auto makeFbo = [this](GLuint& fb, GLuint& color, GLuint* depth, int n) {
    glGenFramebuffers(1, &fb);
    glBindFramebuffer(GL_FRAMEBUFFER, fb);
    glGenRenderbuffers(1, &color);
    glBindRenderbuffer(GL_RENDERBUFFER, color);
    glRenderbufferStorageMultisample(GL_RENDERBUFFER, n > 1 ? n : 0, GL_RGBA8, width, height);
    glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, color);
    if (depth) {
      glGenRenderbuffers(1, depth);
      glBindRenderbuffer(GL_RENDERBUFFER, *depth);
      glRenderbufferStorageMultisample(GL_RENDERBUFFER, n > 1 ? n : 0, GL_DEPTH_COMPONENT24, width, height);
      glFramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, *depth);
    }
    const GLenum status = glCheckFramebufferStatus(GL_FRAMEBUFFER);
    if (status != GL_FRAMEBUFFER_COMPLETE) {
      throw RuntimeError("GL: framebuffer incomplete (status " + hex(static_cast<EGLint>(status)) + ")");
    }
  };
  makeFbo(fbo, colorRb, &depthRb, samples);
  if (samples > 1) makeFbo(resolveFbo, resolveRb, nullptr, 1);
  checkGl("framebuffer setup");
}

void OffscreenRenderer::Impl::createShadowMap() {
  if (!looks.shadows) return;
  GLint maxTexture = 0;
  glGetIntegerv(GL_MAX_TEXTURE_SIZE, &maxTexture);
  if (looks.shadowMapSize < 16 || looks.shadowMapSize > maxTexture) {
    throw RuntimeError("GL: shadow map size " + std::to_string(looks.shadowMapSize) + " must be in [16, " +
                       std::to_string(maxTexture) + "]");
  }
  glGenTextures(1, &shadowTex);
  glBindTexture(GL_TEXTURE_2D, shadowTex);
  glTexImage2D(GL_TEXTURE_2D, 0, GL_DEPTH_COMPONENT24, looks.shadowMapSize, looks.shadowMapSize, 0,
               GL_DEPTH_COMPONENT, GL_UNSIGNED_INT, nullptr);
  // Linear + compare: each lookup is a bilinear blend of four depth comparisons.
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_COMPARE_MODE, GL_COMPARE_REF_TO_TEXTURE);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_COMPARE_FUNC, GL_LEQUAL);
  glBindTexture(GL_TEXTURE_2D, 0);
  glGenFramebuffers(1, &shadowFbo);
  glBindFramebuffer(GL_FRAMEBUFFER, shadowFbo);
  glFramebufferTexture2D(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_TEXTURE_2D, shadowTex, 0);
  glDrawBuffer(GL_NONE);
  glReadBuffer(GL_NONE);
  const GLenum status = glCheckFramebufferStatus(GL_FRAMEBUFFER);
  if (status != GL_FRAMEBUFFER_COMPLETE) {
    throw RuntimeError("GL: shadow framebuffer incomplete (status " + hex(static_cast<EGLint>(status)) + ")");
  }
  checkGl("shadow map setup");
}

void OffscreenRenderer::Impl::createProgram() {
  program = linkProgram(kVertexShader, kFragmentShader);
  uModel = glGetUniformLocation(program, "uModel");
  uNormalMatrix = glGetUniformLocation(program, "uNormalMatrix");
  uView = glGetUniformLocation(program, "uView");
  uProj = glGetUniformLocation(program, "uProj");
  uColor = glGetUniformLocation(program, "uColor");
  uRoughness = glGetUniformLocation(program, "uRoughness");
  uEye = glGetUniformLocation(program, "uEye");
  uLightDir = glGetUniformLocation(program, "uLightDir");
  uCheckerCell = glGetUniformLocation(program, "uCheckerCell");
  uInvGamma = glGetUniformLocation(program, "uInvGamma");
  uLightViewProj = glGetUniformLocation(program, "uLightViewProj");
  uShadows = glGetUniformLocation(program, "uShadows");
  uShadowMap = glGetUniformLocation(program, "uShadowMap");
  uShadowBias = glGetUniformLocation(program, "uShadowBias");
  shadowProgram = linkProgram(kShadowVertexShader, kShadowFragmentShader);
  uLightMvp = glGetUniformLocation(shadowProgram, "uLightMvp");
  backgroundProgram = linkProgram(kBackgroundVertexShader, kBackgroundFragmentShader);
  uTop = glGetUniformLocation(backgroundProgram, "uTop");
  uBottom = glGetUniformLocation(backgroundProgram, "uBottom");
  uHeight = glGetUniformLocation(backgroundProgram, "uHeight");
  uBgInvGamma = glGetUniformLocation(backgroundProgram, "uInvGamma");
  splatProgram = linkProgram(kSplatVertexShader, kSplatFragmentShader);
  uSplatView = glGetUniformLocation(splatProgram, "uView");
  uSplatProj = glGetUniformLocation(splatProgram, "uProj");
  uSplatViewport = glGetUniformLocation(splatProgram, "uViewport");
  uSplatInvGamma = glGetUniformLocation(splatProgram, "uInvGamma");
  uSplatLightDir = glGetUniformLocation(splatProgram, "uLightDir");
  splatShadowProgram = linkProgram(kSplatShadowVertexShader, kSplatShadowFragmentShader);
  uSplatShadowLvp = glGetUniformLocation(splatShadowProgram, "uLightViewProj");
  uSplatShadowMapSize = glGetUniformLocation(splatShadowProgram, "uMapSize");
  // 16 floats per splat, one instance each: centre, covariance (6), colour, opacity, normal.
  glGenVertexArrays(1, &splatVao);
  glGenBuffers(1, &splatVbo);
  glBindVertexArray(splatVao);
  glBindBuffer(GL_ARRAY_BUFFER, splatVbo);
  const GLsizei splatStride = kSplatFloats * sizeof(float);
  const int sizes[6] = {3, 3, 3, 3, 1, 3};
  std::size_t offset = 0;
  for (GLuint loc = 0; loc < 6; ++loc) {
    glEnableVertexAttribArray(loc);
    glVertexAttribPointer(loc, sizes[loc], GL_FLOAT, GL_FALSE, splatStride, reinterpret_cast<const void*>(offset));
    glVertexAttribDivisor(loc, 1);
    offset += std::size_t(sizes[loc]) * sizeof(float);
  }
  glBindVertexArray(0);
  glBindBuffer(GL_ARRAY_BUFFER, 0);
  // Core profile: a draw needs a vertex array, even with no attributes. Bound once here so the
  // object exists from the start (GL creates a vertex array at its first bind).
  glGenVertexArrays(1, &emptyVao);
  glBindVertexArray(emptyVao);
  glBindVertexArray(0);
  checkGl("shader program setup");
}

GpuMesh OffscreenRenderer::Impl::upload(const TriangleMesh& mesh) const {
  validateMesh(mesh, "uploadMesh");
  GpuMesh g;
  glGenVertexArrays(1, &g.vao);
  glGenBuffers(1, &g.vbo);
  glGenBuffers(1, &g.ebo);
  g.live = true;
  glBindVertexArray(g.vao);
  glBindBuffer(GL_ARRAY_BUFFER, g.vbo);
  glBindBuffer(GL_ELEMENT_ARRAY_BUFFER, g.ebo);  // recorded in the vertex array
  const GLsizei stride = 6 * sizeof(float);
  glEnableVertexAttribArray(0);
  glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, stride, nullptr);
  glEnableVertexAttribArray(1);
  glVertexAttribPointer(1, 3, GL_FLOAT, GL_FALSE, stride, reinterpret_cast<const void*>(3 * sizeof(float)));
  glBindVertexArray(0);
  try {
    fill(g, mesh);
  } catch (...) {  // e.g. GL_OUT_OF_MEMORY: do not leak the names
    glDeleteBuffers(1, &g.vbo);
    glDeleteBuffers(1, &g.ebo);
    glDeleteVertexArrays(1, &g.vao);
    throw;
  }
  return g;
}

// (Re)allocates the buffers' storage with the mesh's data: glBufferData releases the old
// storage, and the vertex array keeps pointing at the same buffer names.
void OffscreenRenderer::Impl::fill(GpuMesh& g, const TriangleMesh& mesh) const {
  const std::vector<float> vertices = interleave(mesh);
  glBindVertexArray(g.vao);
  glBindBuffer(GL_ARRAY_BUFFER, g.vbo);
  glBufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(vertices.size() * sizeof(float)), vertices.data(),
               GL_STATIC_DRAW);
  glBufferData(GL_ELEMENT_ARRAY_BUFFER, static_cast<GLsizeiptr>(mesh.indices.size() * sizeof(std::uint32_t)),
               mesh.indices.data(), GL_STATIC_DRAW);
  glBindVertexArray(0);
  g.indexCount = static_cast<GLsizei>(mesh.indices.size());
  g.bounds.setEmpty();
  for (const Vec3f& p : mesh.positions) g.bounds.extend(p);
  checkGl("mesh upload");
}

GpuMesh& OffscreenRenderer::Impl::liveMesh(int handle, const char* who) {
  if (handle < 0 || handle >= static_cast<int>(meshes.size())) {
    throw RuntimeError(std::string(who) + ": invalid mesh handle " + std::to_string(handle));
  }
  GpuMesh& m = meshes[static_cast<std::size_t>(handle)];
  if (!m.live) throw RuntimeError(std::string(who) + ": mesh handle " + std::to_string(handle) + " was freed");
  return m;
}

// Renders the depth of every recorded mesh and splat as the light sees it into the shadow map.
// Returns false (nothing drawn) when shadows are off or nothing that casts was recorded.
bool OffscreenRenderer::Impl::renderShadowMap(Eigen::Matrix4d& lightViewProj) {
  if (!looks.shadows) return false;
  Eigen::AlignedBox3d casters;
  for (const DrawCall& c : calls) {
    if (!c.isMesh) continue;
    const GpuMesh& m = meshOf(c);
    if (m.indexCount == 0 || m.bounds.isEmpty()) continue;
    for (int k = 0; k < 8; ++k) {
      const Eigen::Vector3f corner = m.bounds.corner(static_cast<Eigen::AlignedBox3f::CornerType>(k));
      casters.extend((c.model * corner.homogeneous()).head<3>().cast<double>());
    }
  }
  for (const Splat& sp : splats) {  // the centre, grown by 3 standard deviations of the widest axis
    const double reach = 3.0 * std::sqrt(std::max(0.0f, sp.covariance.diagonal().maxCoeff()));
    casters.extend(sp.centre.cast<double>() - Vec3::Constant(reach));
    casters.extend(sp.centre.cast<double>() + Vec3::Constant(reach));
  }
  if (casters.isEmpty() || !casters.min().allFinite() || !casters.max().allFinite()) return false;
  lightViewProj = lightViewProjection(casters, looks.shadowMapSize);
  glBindFramebuffer(GL_FRAMEBUFFER, shadowFbo);
  glViewport(0, 0, looks.shadowMapSize, looks.shadowMapSize);
  glClearDepth(1.0);
  glClear(GL_DEPTH_BUFFER_BIT);
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_LESS);
  // Slope-scaled offset: a lit surface must not shadow itself ("acne") where its depth in the
  // map, sampled at texel centres, is a little nearer than the surface at the pixel.
  glEnable(GL_POLYGON_OFFSET_FILL);
  glPolygonOffset(2.0f, 4.0f);
  glUseProgram(shadowProgram);
  const Mat4f lvp = lightViewProj.cast<float>();
  for (const DrawCall& c : calls) {
    if (!c.isMesh) continue;
    const GpuMesh& m = meshOf(c);
    if (m.indexCount == 0) continue;
    const Mat4f mvp = lvp * c.model;
    glUniformMatrix4fv(uLightMvp, 1, GL_FALSE, mvp.data());
    glBindVertexArray(m.vao);
    glDrawElements(GL_TRIANGLES, m.indexCount, GL_UNSIGNED_INT, nullptr);
  }
  if (!splats.empty()) {
    uploadSplats();
    glUseProgram(splatShadowProgram);
    glUniformMatrix4fv(uSplatShadowLvp, 1, GL_FALSE, lvp.data());
    glUniform1f(uSplatShadowMapSize, static_cast<float>(looks.shadowMapSize));
    glBindVertexArray(splatVao);
    glDrawArraysInstanced(GL_TRIANGLE_STRIP, 0, 4, static_cast<GLsizei>(splats.size()));
  }
  glBindVertexArray(0);
  glDisable(GL_POLYGON_OFFSET_FILL);
  checkGl("shadow pass");
  return true;
}

void OffscreenRenderer::Impl::drawBackground() {
  glDisable(GL_DEPTH_TEST);
  glDepthMask(GL_FALSE);
  glUseProgram(backgroundProgram);
  glUniform3f(uTop, background.top[0], background.top[1], background.top[2]);
  glUniform3f(uBottom, background.bottom[0], background.bottom[1], background.bottom[2]);
  glUniform1f(uHeight, static_cast<float>(height));
  glUniform1f(uBgInvGamma, 1.0f / kGamma);
  glBindVertexArray(emptyVao);
  glDrawArrays(GL_TRIANGLES, 0, 3);
  glBindVertexArray(0);
  glDepthMask(GL_TRUE);
  glEnable(GL_DEPTH_TEST);
}

void OffscreenRenderer::Impl::draw(const GpuMesh& m, const DrawCall& c, bool countSamples) {
  const Eigen::Matrix3f linear = c.model.topLeftCorner<3, 3>();
  const Eigen::Matrix3f normalMatrix = linear.inverse().transpose();
  glUniformMatrix4fv(uModel, 1, GL_FALSE, c.model.data());  // Eigen is column-major, like GL
  glUniformMatrix3fv(uNormalMatrix, 1, GL_FALSE, normalMatrix.data());
  glUniform3f(uColor, c.color[0], c.color[1], c.color[2]);
  glUniform1f(uRoughness, c.roughness);
  glUniform1f(uCheckerCell, c.checkerCell);
  if (m.indexCount == 0) return;
  if (countSamples) {
    if (queriesUsed == queries.size()) {
      queries.push_back(0);
      glGenQueries(1, &queries.back());
    }
    glBeginQuery(GL_SAMPLES_PASSED, queries[queriesUsed++]);
  }
  glBindVertexArray(m.vao);
  glDrawElements(GL_TRIANGLES, m.indexCount, GL_UNSIGNED_INT, nullptr);
  glBindVertexArray(0);
  if (countSamples) glEndQuery(GL_SAMPLES_PASSED);
}

std::uint64_t OffscreenRenderer::Impl::collectMeshSamples() const {
  std::uint64_t total = 0;
  for (std::size_t i = 0; i < queriesUsed; ++i) {
    GLuint64 samples = 0;
    glGetQueryObjectui64v(queries[i], GL_QUERY_RESULT, &samples);  // waits for the draw
    total += samples;
  }
  checkGl("endFrame (occlusion queries)");
  // Samples -> pixels: every covered pixel counts at least 1.
  const auto perPixel = static_cast<std::uint64_t>(looks.samples);
  return (total + perPixel - 1) / perPixel;
}

void OffscreenRenderer::Impl::destroy() {
  if (display == EGL_NO_DISPLAY) return;
  if (context != EGL_NO_CONTEXT) {
    eglBindAPI(EGL_OPENGL_API);
    if (eglMakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, context)) {
      auto freeMesh = [](GpuMesh& m) {
        glDeleteBuffers(1, &m.vbo);  // zero names are ignored by GL
        glDeleteBuffers(1, &m.ebo);
        glDeleteVertexArrays(1, &m.vao);
      };
      for (GpuMesh& m : meshes) freeMesh(m);
      freeMesh(ground);
      if (!queries.empty()) glDeleteQueries(static_cast<GLsizei>(queries.size()), queries.data());
      glDeleteProgram(program);
      glDeleteProgram(shadowProgram);
      glDeleteProgram(backgroundProgram);
      glDeleteProgram(splatProgram);
      glDeleteProgram(splatShadowProgram);
      glDeleteBuffers(1, &splatVbo);
      glDeleteVertexArrays(1, &splatVao);
      glDeleteVertexArrays(1, &emptyVao);
      glDeleteRenderbuffers(1, &colorRb);
      glDeleteRenderbuffers(1, &depthRb);
      glDeleteFramebuffers(1, &fbo);
      glDeleteRenderbuffers(1, &resolveRb);
      glDeleteFramebuffers(1, &resolveFbo);
      glDeleteTextures(1, &shadowTex);
      glDeleteFramebuffers(1, &shadowFbo);
      eglMakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
    }
    eglDestroyContext(display, context);
    context = EGL_NO_CONTEXT;
  }
  display = EGL_NO_DISPLAY;  // never terminated: see "EGL display lifetime" above
}

OffscreenRenderer::OffscreenRenderer(int width, int height, const Looks& looks, GlDevice device) {
  if (width <= 0 || height <= 0) {
    throw RuntimeError("renderer: image size " + std::to_string(width) + "x" + std::to_string(height) +
                       " must be positive");
  }
  // Built step by step inside impl_, so a throw part-way frees what was already created.
  impl_ = std::make_unique<Impl>(width, height, looks, device);
  impl_->createContext();
  impl_->createFramebuffer();
  impl_->createShadowMap();
  impl_->createProgram();

  TriangleMesh quad;
  quad.positions = {Vec3f(-1, 0, -1), Vec3f(1, 0, -1), Vec3f(1, 0, 1), Vec3f(-1, 0, 1)};
  quad.normals.assign(4, Vec3f(0, 1, 0));
  quad.indices = {0, 2, 1, 0, 3, 2};  // counter-clockwise seen from +y
  impl_->ground = impl_->upload(quad);
}

OffscreenRenderer::~OffscreenRenderer() = default;

int OffscreenRenderer::width() const { return impl_->width; }
int OffscreenRenderer::height() const { return impl_->height; }
const Looks& OffscreenRenderer::looks() const { return impl_->looks; }

const std::string& OffscreenRenderer::deviceDescription() const { return impl_->description; }

int OffscreenRenderer::uploadMesh(const TriangleMesh& mesh) {
  Impl& r = *impl_;
  if (r.meshes.size() >= static_cast<std::size_t>(std::numeric_limits<int>::max())) {
    throw RuntimeError("uploadMesh: out of mesh handles");
  }
  r.makeCurrent();
  r.meshes.push_back(r.upload(mesh));
  return static_cast<int>(r.meshes.size()) - 1;
}

void OffscreenRenderer::updateMesh(int handle, const TriangleMesh& mesh) {
  Impl& r = *impl_;
  GpuMesh& g = r.liveMesh(handle, "updateMesh");
  validateMesh(mesh, "updateMesh");
  r.makeCurrent();
  r.fill(g, mesh);
}

void OffscreenRenderer::freeMesh(int handle) {
  Impl& r = *impl_;
  GpuMesh& g = r.liveMesh(handle, "freeMesh");
  r.makeCurrent();
  glDeleteBuffers(1, &g.vbo);
  glDeleteBuffers(1, &g.ebo);
  glDeleteVertexArrays(1, &g.vao);
  g = GpuMesh{};  // names 0, not live
  r.checkGl("freeMesh");
}

MeshStats OffscreenRenderer::meshStats() const {
  const Impl& r = *impl_;
  r.makeCurrent();
  MeshStats stats;
  // Sizes as the driver reports them, not as this class remembers them. GL_COPY_READ_BUFFER
  // is a binding point that no draw state depends on.
  auto bufferBytes = [](GLuint buffer) {
    GLint64 size = 0;
    glBindBuffer(GL_COPY_READ_BUFFER, buffer);
    glGetBufferParameteri64v(GL_COPY_READ_BUFFER, GL_BUFFER_SIZE, &size);
    return static_cast<std::size_t>(size);
  };
  for (const GpuMesh& g : r.meshes) {
    if (!g.live) continue;
    ++stats.liveMeshes;
    stats.gpuBytes += bufferBytes(g.vbo) + bufferBytes(g.ebo);
  }
  glBindBuffer(GL_COPY_READ_BUFFER, 0);
  r.checkGl("meshStats");
  return stats;
}

void OffscreenRenderer::beginFrame(const Camera& camera, const Color& background, const ClipRange& clip) {
  beginFrame(camera, Background{background, background}, clip);
}

void OffscreenRenderer::beginFrame(const Camera& camera, const Background& background, const ClipRange& clip) {
  Impl& r = *impl_;
  for (const Color* c : {&background.top, &background.bottom})
    for (float v : *c)
      if (!(v >= 0.0f && v <= 1.0f)) throw RuntimeError("beginFrame: background colours must be in [0, 1]");
  r.view = viewMatrix(camera);  // both throw on a degenerate camera or clip range
  r.proj = projectionMatrix(camera, double(r.width) / double(r.height), clip.zNear, clip.zFar);
  r.eye = camera.eye.cast<float>();
  r.background = background;
  r.calls.clear();
  r.splats.clear();
  r.splatsUploaded = false;
  r.queriesUsed = 0;
  r.inFrame = true;
}

void OffscreenRenderer::drawGround(double y, double cx, double cz, double halfExtent, const Color& color) {
  Impl& r = *impl_;
  if (!r.inFrame) throw RuntimeError("drawGround called outside beginFrame/endFrame");
  if (!(halfExtent > 0.0) || !std::isfinite(halfExtent) || !std::isfinite(y) || !std::isfinite(cx) ||
      !std::isfinite(cz)) {
    throw RuntimeError("drawGround: position must be finite and halfExtent > 0 m");
  }
  Mat4f model = Mat4f::Identity();
  model(0, 0) = static_cast<float>(halfExtent);
  model(2, 2) = static_cast<float>(halfExtent);
  model(0, 3) = static_cast<float>(cx);
  model(1, 3) = static_cast<float>(y);
  model(2, 3) = static_cast<float>(cz);
  // Matte: a rough surface has a faint, wide highlight. 16 x 16 checker cells.
  r.calls.push_back({-1, model, color, 0.9f, static_cast<float>(halfExtent / 8.0), false});
}

void OffscreenRenderer::drawMesh(int handle, const Mat4f& model, const Color& color, float roughness) {
  Impl& r = *impl_;
  if (!r.inFrame) throw RuntimeError("drawMesh called outside beginFrame/endFrame");
  r.liveMesh(handle, "drawMesh");
  if (!model.allFinite()) throw RuntimeError("drawMesh: model matrix is not finite");
  if (!(std::abs(model.topLeftCorner<3, 3>().determinant()) > 0.0f)) {
    throw RuntimeError("drawMesh: model matrix is singular");
  }
  if (!(roughness >= 0.0f && roughness <= 1.0f)) throw RuntimeError("drawMesh: roughness must be in [0, 1]");
  r.calls.push_back({handle, model, color, roughness, 0.0f, true});
}

void OffscreenRenderer::drawSplats(const std::vector<Splat>& splats) {
  Impl& r = *impl_;
  if (!r.inFrame) throw RuntimeError("drawSplats called outside beginFrame/endFrame");
  for (std::size_t i = 0; i < splats.size(); ++i) {
    const Splat& s = splats[i];
    auto fail = [i](const std::string& what) { throw RuntimeError("drawSplats: splat " + std::to_string(i) + ": " + what); };
    if (!s.centre.allFinite()) fail("centre is not finite");
    const Eigen::Matrix3f& c = s.covariance;
    if (!c.allFinite() || !c.isApprox(c.transpose(), 1e-5f)) fail("covariance is not finite and symmetric");
    if (Eigen::LLT<Eigen::Matrix3f>(c).info() != Eigen::Success || !(c.determinant() > 0.0f))
      fail("covariance is not positive definite");
    for (float v : s.color)
      if (!(v >= 0.0f && v <= 1.0f)) fail("colour must be in [0, 1]");
    if (!(s.opacity > 0.0f && s.opacity <= 1.0f)) fail("opacity must be in (0, 1]");
    const float n2 = s.normal.squaredNorm();
    if (!(n2 == 0.0f || std::abs(n2 - 1.0f) < 1e-3f)) fail("normal must be zero (unlit) or unit");
  }
  r.splats.insert(r.splats.end(), splats.begin(), splats.end());
}

// Back to front by the depth of the centre (ties: call order).
void OffscreenRenderer::Impl::uploadSplats() {
  if (splatsUploaded) return;
  const std::size_t n = splats.size();
  std::vector<std::pair<float, std::uint32_t>> order(n);
  for (std::size_t i = 0; i < n; ++i) {
    const Eigen::Vector4f t = view * splats[i].centre.homogeneous();
    order[i] = {t.z(), static_cast<std::uint32_t>(i)};  // more negative z: farther
  }
  std::sort(order.begin(), order.end());
  std::vector<float> data;
  data.reserve(kSplatFloats * n);
  for (const auto& o : order) {
    const Splat& s = splats[o.second];
    const Eigen::Matrix3f& c = s.covariance;
    const float row[kSplatFloats] = {s.centre.x(), s.centre.y(), s.centre.z(), c(0, 0),    c(0, 1),    c(0, 2),
                                     c(1, 1),      c(1, 2),      c(2, 2),      s.color[0], s.color[1], s.color[2],
                                     s.opacity,    s.normal.x(), s.normal.y(), s.normal.z()};
    data.insert(data.end(), row, row + kSplatFloats);
  }
  glBindBuffer(GL_ARRAY_BUFFER, splatVbo);
  glBufferData(GL_ARRAY_BUFFER, static_cast<GLsizeiptr>(data.size() * sizeof(float)), data.data(), GL_STREAM_DRAW);
  glBindBuffer(GL_ARRAY_BUFFER, 0);
  splatsUploaded = true;
}

// The uploaded splats (uploadSplats), in one instanced draw with blending "over" on
// premultiplied colour; depth tested against the meshes, not written.
void OffscreenRenderer::Impl::drawSplats() {
  if (splats.empty()) return;
  const std::size_t n = splats.size();
  uploadSplats();
  glUseProgram(splatProgram);
  glUniformMatrix4fv(uSplatView, 1, GL_FALSE, view.data());
  glUniformMatrix4fv(uSplatProj, 1, GL_FALSE, proj.data());
  glUniform2f(uSplatViewport, static_cast<float>(width), static_cast<float>(height));
  glUniform1f(uSplatInvGamma, 1.0f / kGamma);
  const Vec3f light = lightDirection().cast<float>();
  glUniform3f(uSplatLightDir, light.x(), light.y(), light.z());
  glEnable(GL_DEPTH_TEST);
  glDepthMask(GL_FALSE);
  glEnable(GL_BLEND);
  glBlendFunc(GL_ONE, GL_ONE_MINUS_SRC_ALPHA);
  glBindVertexArray(splatVao);
  glDrawArraysInstanced(GL_TRIANGLE_STRIP, 0, 4, static_cast<GLsizei>(n));
  glBindVertexArray(0);
  glDisable(GL_BLEND);
  glDepthMask(GL_TRUE);
  splats.clear();
  splatsUploaded = false;
  checkGl("drawSplats");
}

Image OffscreenRenderer::endFrame() {
  Impl& r = *impl_;
  if (!r.inFrame) throw RuntimeError("endFrame called without beginFrame");
  r.makeCurrent();
  r.inFrame = false;
  const double start = nowSeconds();

  Eigen::Matrix4d lightViewProj = Eigen::Matrix4d::Identity();
  const bool shadows = r.renderShadowMap(lightViewProj);

  glBindFramebuffer(GL_FRAMEBUFFER, r.fbo);
  glViewport(0, 0, r.width, r.height);
  glClearDepth(1.0);
  glClear(GL_DEPTH_BUFFER_BIT);  // the background covers every pixel
  r.drawBackground();
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_LESS);
  // No culling: meshes are closed so hidden faces fail the depth test anyway, and an open or
  // inside-out mesh still shows up instead of vanishing.
  glDisable(GL_CULL_FACE);
  glDisable(GL_BLEND);
  glUseProgram(r.program);
  glUniformMatrix4fv(r.uView, 1, GL_FALSE, r.view.data());
  glUniformMatrix4fv(r.uProj, 1, GL_FALSE, r.proj.data());
  glUniform3f(r.uEye, r.eye.x(), r.eye.y(), r.eye.z());
  const Vec3f light = lightDirection().cast<float>();
  glUniform3f(r.uLightDir, light.x(), light.y(), light.z());
  glUniform1f(r.uInvGamma, 1.0f / kGamma);
  const Mat4f lvp = lightViewProj.cast<float>();
  glUniformMatrix4fv(r.uLightViewProj, 1, GL_FALSE, lvp.data());
  glUniform1i(r.uShadows, shadows ? 1 : 0);
  glActiveTexture(GL_TEXTURE0);
  glBindTexture(GL_TEXTURE_2D, shadows ? r.shadowTex : 0);
  glUniform1i(r.uShadowMap, 0);
  // A constant bias of 1/(2 mapSize) of the map's depth range (the caster's depth extent: for a
  // 1 m scene and a 1024 map, 0.5 mm) against rounding; the shadow pass's slope-scaled polygon
  // offset does the rest.
  glUniform1f(r.uShadowBias, 0.5f / static_cast<float>(r.looks.shadowMapSize));
  for (const DrawCall& c : r.calls) {
    // Push the ground back in depth so faces of bodies resting on it (same height) win the depth
    // test instead of z-fighting.
    if (!c.isMesh) {
      glEnable(GL_POLYGON_OFFSET_FILL);
      glPolygonOffset(1.0f, 1.0f);
    }
    r.draw(r.meshOf(c), c, c.isMesh);
    if (!c.isMesh) glDisable(GL_POLYGON_OFFSET_FILL);
  }
  r.checkGl("endFrame (draw)");
  r.calls.clear();
  r.drawSplats();

  GLuint readFbo = r.fbo;
  if (r.resolveFbo) {  // average the samples of each pixel
    glBindFramebuffer(GL_READ_FRAMEBUFFER, r.fbo);
    glBindFramebuffer(GL_DRAW_FRAMEBUFFER, r.resolveFbo);
    glBlitFramebuffer(0, 0, r.width, r.height, 0, 0, r.width, r.height, GL_COLOR_BUFFER_BIT, GL_NEAREST);
    readFbo = r.resolveFbo;
  }
  glFinish();
  const double drawn = nowSeconds();
  Image image;
  image.width = r.width;
  image.height = r.height;
  image.meshSamples = r.collectMeshSamples();
  const std::size_t stride = static_cast<std::size_t>(r.width) * 4;
  std::vector<std::uint8_t> bottomUp(stride * static_cast<std::size_t>(r.height));
  glBindFramebuffer(GL_READ_FRAMEBUFFER, readFbo);
  glReadBuffer(GL_COLOR_ATTACHMENT0);
  glPixelStorei(GL_PACK_ALIGNMENT, 1);
  glReadPixels(0, 0, r.width, r.height, GL_RGBA, GL_UNSIGNED_BYTE, bottomUp.data());
  r.checkGl("endFrame (glReadPixels)");
  // GL's row 0 is the bottom row; images are stored top row first.
  image.rgba.resize(bottomUp.size());
  for (int y = 0; y < r.height; ++y) {
    std::memcpy(image.rgba.data() + static_cast<std::size_t>(y) * stride,
                bottomUp.data() + static_cast<std::size_t>(r.height - 1 - y) * stride, stride);
  }
  image.drawSeconds = drawn - start;
  image.readSeconds = nowSeconds() - drawn;
  return image;
}

}  // namespace physketch::render
