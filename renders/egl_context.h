#pragma once
// An OpenGL context without a window, from EGL: Mesa's surfaceless platform on machines
// without a GPU (llvmpipe), the EGL device platform on GPU machines, chosen automatically
// with an override. libEGL is loaded at run time (dlopen), so the tofu binary starts and
// every other command works on a machine without it; only rendering reports what to
// install.

#include <memory>
#include <optional>
#include <stdexcept>
#include <string>

namespace tofu::renders {

/// Rendering cannot start on this machine (no libEGL, no usable EGL platform or device,
/// no OpenGL context). The message names the fix. The CLI exits with code 2.
class RenderUnavailableError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct EglOptions {
  /// "auto" (a GPU device if EGL enumerates one with a DRM node, else surfaceless),
  /// "surfaceless" or "device". Unset: $TOFU_EGL_PLATFORM, else $EGL_PLATFORM when it
  /// names one of these, else "auto".
  std::optional<std::string> platform;
  /// Device platform: index into eglQueryDevicesEXT. Unset: $TOFU_EGL_DEVICE, else the
  /// first GPU (auto) or device 0.
  std::optional<int> device;
  /// The EGL library to load. Unset: $TOFU_EGL_LIBRARY, else "libEGL.so.1".
  std::optional<std::string> library;
};

/// A current OpenGL (compatibility profile) context on the calling thread, with no
/// surface: MuJoCo renders into its own offscreen framebuffer. One per renderer; the
/// context is released on destruction.
class EglContext {
 public:
  /// Throws RenderUnavailableError (naming the fix) when EGL or a context is unavailable,
  /// core::InputError for a malformed override (unknown platform name).
  explicit EglContext(const EglOptions& options = {});
  ~EglContext();
  EglContext(const EglContext&) = delete;
  EglContext& operator=(const EglContext&) = delete;

  /// Makes this context current on the calling thread again.
  void MakeCurrent();

  const std::string& platform() const;      ///< "surfaceless" or "device N"
  const std::string& gl_renderer() const;   ///< GL_RENDERER, e.g. "llvmpipe (LLVM 15...)"
  const std::string& gl_version() const;    ///< GL_VERSION
  /// True when GL_RENDERER is a software rasteriser (llvmpipe, softpipe, swrast).
  bool software() const;
  /// One line for logs: platform, renderer and version.
  std::string Description() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tofu::renders
