#include "renders/egl_context.h"

#include <dlfcn.h>

#include <cstdlib>
#include <cstring>
#include <mutex>
#include <vector>

// No X11 types in EGL's headers: tofu never opens a display server.
#define EGL_NO_X11
#include <EGL/egl.h>
#include <EGL/eglext.h>
#include <fmt/format.h>

#include "core/error.h"

namespace tofu::renders {
namespace {

constexpr const char* kInstallHint =
    "install libegl1 and libgl1-mesa-dri (Mesa's llvmpipe renders without a GPU; "
    "scripts/setup.sh installs them), or set TOFU_EGL_PLATFORM=surfaceless";

// GL_RENDERER / GL_VERSION / GL_VENDOR (GL/gl.h values; the GL headers are not needed).
constexpr unsigned kGlVendor = 0x1F00;
constexpr unsigned kGlRenderer = 0x1F01;
constexpr unsigned kGlVersion = 0x1F02;
using GlGetStringFn = const unsigned char* (*)(unsigned);

// The entry points of libEGL we use, resolved once per process.
struct EglApi {
  void* library = nullptr;
  std::string library_name;
  PFNEGLGETPROCADDRESSPROC GetProcAddress = nullptr;
  PFNEGLGETERRORPROC GetError = nullptr;
  PFNEGLQUERYSTRINGPROC QueryString = nullptr;
  PFNEGLINITIALIZEPROC Initialize = nullptr;
  PFNEGLCHOOSECONFIGPROC ChooseConfig = nullptr;
  PFNEGLBINDAPIPROC BindAPI = nullptr;
  PFNEGLCREATECONTEXTPROC CreateContext = nullptr;
  PFNEGLDESTROYCONTEXTPROC DestroyContext = nullptr;
  PFNEGLMAKECURRENTPROC MakeCurrent = nullptr;
  PFNEGLGETPLATFORMDISPLAYEXTPROC GetPlatformDisplay = nullptr;
  PFNEGLQUERYDEVICESEXTPROC QueryDevices = nullptr;
  PFNEGLQUERYDEVICESTRINGEXTPROC QueryDeviceString = nullptr;
};

template <typename Fn>
Fn Symbol(void* library, const char* name) {
  return reinterpret_cast<Fn>(dlsym(library, name));
}

// Loads libEGL (once per library name; never unloaded: drivers keep state in it).
const EglApi& LoadEgl(const std::string& library_name) {
  static std::mutex mutex;
  static std::vector<std::unique_ptr<EglApi>> loaded;
  const std::lock_guard<std::mutex> lock(mutex);
  for (const auto& api : loaded) {
    if (api->library_name == library_name) return *api;
  }
  auto api = std::make_unique<EglApi>();
  api->library_name = library_name;
  api->library = dlopen(library_name.c_str(), RTLD_NOW | RTLD_LOCAL);
  if (api->library == nullptr) {
    const char* why = dlerror();
    throw RenderUnavailableError(fmt::format("EGL is not available: cannot load {} ({}); {}",
                                             library_name, why != nullptr ? why : "not found",
                                             kInstallHint));
  }
  void* lib = api->library;
  api->GetProcAddress = Symbol<PFNEGLGETPROCADDRESSPROC>(lib, "eglGetProcAddress");
  api->GetError = Symbol<PFNEGLGETERRORPROC>(lib, "eglGetError");
  api->QueryString = Symbol<PFNEGLQUERYSTRINGPROC>(lib, "eglQueryString");
  api->Initialize = Symbol<PFNEGLINITIALIZEPROC>(lib, "eglInitialize");
  api->ChooseConfig = Symbol<PFNEGLCHOOSECONFIGPROC>(lib, "eglChooseConfig");
  api->BindAPI = Symbol<PFNEGLBINDAPIPROC>(lib, "eglBindAPI");
  api->CreateContext = Symbol<PFNEGLCREATECONTEXTPROC>(lib, "eglCreateContext");
  api->DestroyContext = Symbol<PFNEGLDESTROYCONTEXTPROC>(lib, "eglDestroyContext");
  api->MakeCurrent = Symbol<PFNEGLMAKECURRENTPROC>(lib, "eglMakeCurrent");
  if (api->GetProcAddress == nullptr || api->GetError == nullptr || api->QueryString == nullptr ||
      api->Initialize == nullptr || api->ChooseConfig == nullptr || api->BindAPI == nullptr ||
      api->CreateContext == nullptr || api->DestroyContext == nullptr ||
      api->MakeCurrent == nullptr) {
    throw RenderUnavailableError(fmt::format(
        "EGL is not usable: {} lacks EGL 1.4 entry points; {}", library_name, kInstallHint));
  }
  api->GetPlatformDisplay = reinterpret_cast<PFNEGLGETPLATFORMDISPLAYEXTPROC>(
      api->GetProcAddress("eglGetPlatformDisplayEXT"));
  api->QueryDevices =
      reinterpret_cast<PFNEGLQUERYDEVICESEXTPROC>(api->GetProcAddress("eglQueryDevicesEXT"));
  api->QueryDeviceString = reinterpret_cast<PFNEGLQUERYDEVICESTRINGEXTPROC>(
      api->GetProcAddress("eglQueryDeviceStringEXT"));
  loaded.push_back(std::move(api));
  return *loaded.back();
}

bool HasExtension(const char* list, const char* name) {
  if (list == nullptr) return false;
  const size_t n = std::strlen(name);
  for (const char* p = list; (p = std::strstr(p, name)) != nullptr; p += n) {
    const bool starts = p == list || p[-1] == ' ';
    const bool ends = p[n] == '\0' || p[n] == ' ';
    if (starts && ends) return true;
  }
  return false;
}

std::string EglErrorName(EGLint code) {
  switch (code) {
    case EGL_NOT_INITIALIZED: return "EGL_NOT_INITIALIZED";
    case EGL_BAD_ACCESS: return "EGL_BAD_ACCESS";
    case EGL_BAD_ALLOC: return "EGL_BAD_ALLOC";
    case EGL_BAD_ATTRIBUTE: return "EGL_BAD_ATTRIBUTE";
    case EGL_BAD_CONFIG: return "EGL_BAD_CONFIG";
    case EGL_BAD_CONTEXT: return "EGL_BAD_CONTEXT";
    case EGL_BAD_DISPLAY: return "EGL_BAD_DISPLAY";
    case EGL_BAD_MATCH: return "EGL_BAD_MATCH";
    case EGL_BAD_PARAMETER: return "EGL_BAD_PARAMETER";
    default: return fmt::format("EGL error 0x{:04x}", code);
  }
}

std::string EnvOr(const char* name, const std::string& fallback) {
  const char* value = std::getenv(name);
  return value != nullptr && *value != '\0' ? std::string(value) : fallback;
}

// The platform asked for: option, $TOFU_EGL_PLATFORM, $EGL_PLATFORM (Mesa's own variable,
// honoured when it names a platform we drive), else auto.
std::string RequestedPlatform(const EglOptions& options, std::string* source) {
  if (options.platform) {
    *source = "--egl-platform";
    return *options.platform;
  }
  if (const char* v = std::getenv("TOFU_EGL_PLATFORM"); v != nullptr && *v != '\0') {
    *source = "TOFU_EGL_PLATFORM";
    return v;
  }
  if (const char* v = std::getenv("EGL_PLATFORM");
      v != nullptr && (std::strcmp(v, "surfaceless") == 0 || std::strcmp(v, "device") == 0)) {
    *source = "EGL_PLATFORM";
    return v;
  }
  *source = "default";
  return "auto";
}

std::optional<int> RequestedDevice(const EglOptions& options) {
  if (options.device) return options.device;
  const char* v = std::getenv("TOFU_EGL_DEVICE");
  if (v == nullptr || *v == '\0') return std::nullopt;
  char* end = nullptr;
  const long index = std::strtol(v, &end, 10);
  if (*end != '\0' || index < 0) {
    throw core::InputError({"TOFU_EGL_DEVICE"}, "",
                           fmt::format("expected a device index >= 0, got '{}'", v));
  }
  return static_cast<int>(index);
}

}  // namespace

struct EglContext::Impl {
  const EglApi* api = nullptr;
  EGLDisplay display = EGL_NO_DISPLAY;
  EGLContext context = EGL_NO_CONTEXT;
  std::string platform;
  std::string vendor;
  std::string renderer;
  std::string version;

  std::vector<EGLDeviceEXT> Devices() const {
    if (api->QueryDevices == nullptr) return {};
    EGLint count = 0;
    if (api->QueryDevices(0, nullptr, &count) != EGL_TRUE || count <= 0) return {};
    std::vector<EGLDeviceEXT> devices(static_cast<size_t>(count));
    api->QueryDevices(count, devices.data(), &count);
    devices.resize(static_cast<size_t>(count));
    return devices;
  }

  // A GPU: a device with a DRM node that is not Mesa's software device.
  int FirstGpu(const std::vector<EGLDeviceEXT>& devices) const {
    if (api->QueryDeviceString == nullptr) return -1;
    for (size_t i = 0; i < devices.size(); ++i) {
      const char* extensions = api->QueryDeviceString(devices[i], EGL_EXTENSIONS);
      if (HasExtension(extensions, "EGL_MESA_device_software")) continue;
      if (!HasExtension(extensions, "EGL_EXT_device_drm")) continue;
      const char* file = api->QueryDeviceString(devices[i], EGL_DRM_DEVICE_FILE_EXT);
      if (file != nullptr && *file != '\0') return static_cast<int>(i);
    }
    return -1;
  }

  void OpenDisplay(const EglOptions& options) {
    std::string source;
    const std::string requested = RequestedPlatform(options, &source);
    if (requested != "auto" && requested != "surfaceless" && requested != "device") {
      throw core::InputError({source}, "",
                             fmt::format("unknown EGL platform '{}': expected auto, surfaceless "
                                         "or device",
                                         requested));
    }
    const std::optional<int> device_index = RequestedDevice(options);
    api = &LoadEgl(options.library.value_or(EnvOr("TOFU_EGL_LIBRARY", "libEGL.so.1")));
    const char* client = api->QueryString(EGL_NO_DISPLAY, EGL_EXTENSIONS);
    if (api->GetPlatformDisplay == nullptr || !HasExtension(client, "EGL_EXT_platform_base")) {
      throw RenderUnavailableError(fmt::format(
          "EGL has no platform displays (EGL_EXT_platform_base missing: an old or non-Mesa "
          "libEGL); {}",
          kInstallHint));
    }

    const std::vector<EGLDeviceEXT> devices = Devices();
    std::string choice = requested;
    int index = device_index.value_or(-1);
    if (choice == "auto") {
      const int gpu = HasExtension(client, "EGL_EXT_platform_device") ? FirstGpu(devices) : -1;
      if (device_index || gpu >= 0) {
        choice = "device";
        if (index < 0) index = gpu;
      } else {
        choice = "surfaceless";
      }
    }

    if (choice == "surfaceless") {
      if (!HasExtension(client, "EGL_MESA_platform_surfaceless")) {
        throw RenderUnavailableError(fmt::format(
            "EGL has no surfaceless platform (EGL_MESA_platform_surfaceless): the EGL vendor "
            "library is not Mesa's; {}, or on a GPU machine set TOFU_EGL_PLATFORM=device",
            kInstallHint));
      }
      display = api->GetPlatformDisplay(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, nullptr);
      platform = "surfaceless";
    } else {
      if (!HasExtension(client, "EGL_EXT_platform_device") || devices.empty()) {
        throw RenderUnavailableError(fmt::format(
            "the EGL device platform is not available (no EGL_EXT_platform_device or no "
            "device); set TOFU_EGL_PLATFORM=surfaceless, or {}",
            kInstallHint));
      }
      if (index < 0) index = 0;
      if (index >= static_cast<int>(devices.size())) {
        throw RenderUnavailableError(fmt::format(
            "EGL device {} does not exist ({} device(s): 0..{}); set TOFU_EGL_DEVICE to one of "
            "them or TOFU_EGL_PLATFORM=surfaceless",
            index, devices.size(), devices.size() - 1));
      }
      display = api->GetPlatformDisplay(EGL_PLATFORM_DEVICE_EXT, devices[index], nullptr);
      platform = fmt::format("device {}", index);
    }
    if (display == EGL_NO_DISPLAY) {
      throw RenderUnavailableError(fmt::format("EGL: no display on the {} platform ({}); {}",
                                               platform, EglErrorName(api->GetError()),
                                               kInstallHint));
    }
    EGLint major = 0;
    EGLint minor = 0;
    if (api->Initialize(display, &major, &minor) != EGL_TRUE) {
      throw RenderUnavailableError(fmt::format(
          "EGL: cannot initialise the {} platform ({}): no usable driver; {}", platform,
          EglErrorName(api->GetError()), kInstallHint));
    }
  }

  void CreateContext() {
    // MuJoCo renders into its own framebuffer object and no surface is ever made, but
    // EGL's default surface type is a window, which neither platform offers: ask for
    // pbuffer-capable configs (both platforms have them).
    const EGLint config_attributes[] = {EGL_RED_SIZE,        8, EGL_GREEN_SIZE, 8,
                                        EGL_BLUE_SIZE,       8, EGL_ALPHA_SIZE, 8,
                                        EGL_DEPTH_SIZE,      24, EGL_STENCIL_SIZE, 8,
                                        EGL_SURFACE_TYPE,    EGL_PBUFFER_BIT,
                                        EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT, EGL_NONE};
    EGLConfig config = nullptr;
    EGLint count = 0;
    if (api->ChooseConfig(display, config_attributes, &config, 1, &count) != EGL_TRUE ||
        count < 1) {
      throw RenderUnavailableError(fmt::format(
          "EGL ({}): no RGBA8 + depth24/stencil8 OpenGL config; {}", platform, kInstallHint));
    }
    if (api->BindAPI(EGL_OPENGL_API) != EGL_TRUE) {
      throw RenderUnavailableError(fmt::format(
          "EGL ({}): desktop OpenGL is not supported by this driver; {}", platform, kInstallHint));
    }
    // No attributes: the default is a compatibility-profile context, which MuJoCo 2.2's
    // fixed-function renderer needs.
    context = api->CreateContext(display, config, EGL_NO_CONTEXT, nullptr);
    if (context == EGL_NO_CONTEXT) {
      throw RenderUnavailableError(fmt::format("EGL ({}): cannot create an OpenGL context ({}); {}",
                                               platform, EglErrorName(api->GetError()),
                                               kInstallHint));
    }
    if (api->MakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, context) != EGL_TRUE) {
      throw RenderUnavailableError(fmt::format(
          "EGL ({}): cannot make the context current without a surface ({}); {}", platform,
          EglErrorName(api->GetError()), kInstallHint));
    }
    const auto get_string = reinterpret_cast<GlGetStringFn>(api->GetProcAddress("glGetString"));
    const auto text = [&](unsigned name) {
      const unsigned char* s = get_string != nullptr ? get_string(name) : nullptr;
      return s != nullptr ? std::string(reinterpret_cast<const char*>(s)) : std::string("?");
    };
    vendor = text(kGlVendor);
    renderer = text(kGlRenderer);
    version = text(kGlVersion);
  }
};

EglContext::EglContext(const EglOptions& options) : impl_(std::make_unique<Impl>()) {
  impl_->OpenDisplay(options);
  try {
    impl_->CreateContext();
  } catch (...) {
    if (impl_->context != EGL_NO_CONTEXT) impl_->api->DestroyContext(impl_->display, impl_->context);
    throw;
  }
}

EglContext::~EglContext() {
  // The display stays initialised: other renderers of the process may share it, and
  // eglTerminate would destroy their contexts too.
  if (impl_->context != EGL_NO_CONTEXT) {
    impl_->api->MakeCurrent(impl_->display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
    impl_->api->DestroyContext(impl_->display, impl_->context);
  }
}

void EglContext::MakeCurrent() {
  impl_->api->MakeCurrent(impl_->display, EGL_NO_SURFACE, EGL_NO_SURFACE, impl_->context);
}

const std::string& EglContext::platform() const { return impl_->platform; }
const std::string& EglContext::gl_renderer() const { return impl_->renderer; }
const std::string& EglContext::gl_version() const { return impl_->version; }

bool EglContext::software() const {
  const std::string& r = impl_->renderer;
  return r.find("llvmpipe") != std::string::npos || r.find("softpipe") != std::string::npos ||
         r.find("swrast") != std::string::npos || r.find("Software") != std::string::npos;
}

std::string EglContext::Description() const {
  return fmt::format("EGL {} platform, OpenGL renderer '{}' ({}), version {}{}", impl_->platform,
                     impl_->renderer, impl_->vendor, impl_->version,
                     software() ? " [software rasteriser: CPU rendering]" : "");
}

}  // namespace tofu::renders

// LeakSanitizer (TOFU_SANITIZE builds): Mesa's drivers, LLVM's JIT and libglvnd keep
// process-lifetime allocations, and the EGL display stays initialised on purpose (see
// ~EglContext). Those are not tofu's leaks; everything else is still reported. This
// definition replaces the sanitizer runtime's weak default and is inert without it.
extern "C" __attribute__((used, visibility("default"))) const char* __lsan_default_suppressions() {
  return "leak:swrast_dri.so\n"
         "leak:libLLVM\n"
         "leak:libEGL_mesa.so\n"
         "leak:libglapi.so\n"
         "leak:libGLdispatch.so\n"
         "leak:libEGL.so\n"
         "leak:libGLX\n";
}
