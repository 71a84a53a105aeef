// PluginLibrary (client.h): C++ plug-ins loaded with dlopen (include/tofu/plugin.h).

#include <dlfcn.h>

#include <fmt/format.h>

#include <exception>
#include <memory>
#include <string>
#include <utility>

#include "interface/client.h"

namespace tofu::interface {
namespace {

using VersionFn = int (*)();
using CreateEstimatorFn = api::Estimator* (*)(const char*);
using DestroyEstimatorFn = void (*)(api::Estimator*);
using CreateControllerFn = api::Controller* (*)(const char*);
using DestroyControllerFn = void (*)(api::Controller*);

std::string DlError() {
  const char* error = ::dlerror();
  return error != nullptr ? error : "unknown error";
}

// A symbol of the library, or nullptr.
template <typename Fn>
Fn Symbol(void* handle, const char* name) {
  ::dlerror();
  return reinterpret_cast<Fn>(::dlsym(handle, name));
}

// Runs a call into the plug-in; what escapes it becomes a ClientError naming the plug-in
// and the call. Exceptions cross the boundary as they do for any C++ plug-in (plugin.h:
// same compiler family and standard library).
template <typename Call>
auto Guard(const std::string& who, const char* call, Call&& body) -> decltype(body()) {
  try {
    return body();
  } catch (const ClientError&) {
    throw;
  } catch (const std::exception& e) {
    throw ClientError(fmt::format("{}: {} threw: {}", who, call, e.what()));
  } catch (...) {
    throw ClientError(fmt::format("{}: {} threw an exception that is not a std::exception", who,
                                  call));
  }
}

// The plug-in's object, destroyed by the library that made it; the library stays loaded
// while the object lives.
template <typename Api, typename Destroy>
class Owned {
 public:
  Owned(std::shared_ptr<PluginLibrary> library, Api* object, Destroy destroy)
      : library_(std::move(library)), object_(object), destroy_(destroy) {}
  ~Owned() { destroy_(object_); }
  Owned(const Owned&) = delete;
  Owned& operator=(const Owned&) = delete;
  Api& operator*() const { return *object_; }

 private:
  std::shared_ptr<PluginLibrary> library_;  // outlives object_ (destroyed after it)
  Api* object_;
  Destroy destroy_;
};

class PluginEstimator final : public api::Estimator {
 public:
  PluginEstimator(std::string who, std::shared_ptr<PluginLibrary> library,
                  api::Estimator* estimator, DestroyEstimatorFn destroy)
      : who_(std::move(who)), estimator_(std::move(library), estimator, destroy) {}

  void Start(const api::EstimatorSetup& setup) override {
    Guard(who_, "Start", [&] { (*estimator_).Start(setup); });
  }
  void Add(const api::Measurement& measurement, std::vector<api::Estimate>* out) override {
    try {
      (*estimator_).Add(measurement, out);
    } catch (...) {
      // The call's name with the sample's stamp, formatted only on failure.
      const std::string call = fmt::format("Add (measurement t_ns={}, sensor {})",
                                           measurement.t_ns, measurement.sensor);
      Guard(who_, call.c_str(), [] { throw; });
    }
  }
  void Finish(std::vector<api::Estimate>* out) override {
    Guard(who_, "Finish", [&] { (*estimator_).Finish(out); });
  }
  std::string ReportJson() const override {
    return Guard(who_, "ReportJson", [&] { return (*estimator_).ReportJson(); });
  }

 private:
  std::string who_;
  Owned<api::Estimator, DestroyEstimatorFn> estimator_;
};

class PluginController final : public api::Controller {
 public:
  PluginController(std::string who, std::shared_ptr<PluginLibrary> library,
                   api::Controller* controller, DestroyControllerFn destroy)
      : who_(std::move(who)), controller_(std::move(library), controller, destroy) {}

  void Start(const api::ControllerSetup& setup) override {
    Guard(who_, "Start", [&] { (*controller_).Start(setup); });
  }
  api::ControlCommand Compute(const api::ControlState& state,
                              const api::ControlReference& reference) override {
    try {
      return (*controller_).Compute(state, reference);
    } catch (...) {
      const std::string call = fmt::format("Compute (t_ns={})", state.t_ns);
      return Guard(who_, call.c_str(), []() -> api::ControlCommand { throw; });
    }
  }

 private:
  std::string who_;
  Owned<api::Controller, DestroyControllerFn> controller_;
};

}  // namespace

std::shared_ptr<PluginLibrary> PluginLibrary::Open(const std::filesystem::path& library) {
  std::error_code ec;
  // dlopen searches the library path for a name without '/': a plug-in is a file.
  std::filesystem::path path = std::filesystem::absolute(library, ec);
  if (ec) path = library;
  std::shared_ptr<PluginLibrary> plugin(new PluginLibrary());
  plugin->path_ = path;
  plugin->handle_ = ::dlopen(path.c_str(), RTLD_NOW | RTLD_LOCAL);
  if (plugin->handle_ == nullptr) {
    throw ClientError(fmt::format("plug-in {}: cannot load it: {}", path.string(), DlError()));
  }
  const auto version = Symbol<VersionFn>(plugin->handle_, "tofu_plugin_api_version");
  if (version == nullptr) {
    throw ClientError(fmt::format(
        "plug-in {}: not a tofu plug-in: it defines no tofu_plugin_api_version "
        "(TOFU_PLUGIN_DECLARE_VERSION() of tofu/plugin.h)",
        path.string()));
  }
  const int plugin_version = version();
  if (plugin_version != api::kApiVersion) {
    throw ClientError(fmt::format(
        "plug-in {}: built against tofu API version {}, this tofu speaks version {}; rebuild "
        "it against this tofu's headers",
        path.string(), plugin_version, api::kApiVersion));
  }
  return plugin;
}

PluginLibrary::~PluginLibrary() {
  if (handle_ != nullptr) ::dlclose(handle_);
}

std::unique_ptr<api::Estimator> PluginLibrary::CreateEstimator(const std::string& name) {
  const std::string who = fmt::format("plugin:{} ({})", name, path_.string());
  const auto create = Symbol<CreateEstimatorFn>(handle_, "tofu_create_estimator");
  const auto destroy = Symbol<DestroyEstimatorFn>(handle_, "tofu_destroy_estimator");
  if (create == nullptr || destroy == nullptr) {
    throw ClientError(fmt::format(
        "{}: the library makes no estimators (no tofu_create_estimator and "
        "tofu_destroy_estimator: TOFU_PLUGIN_ESTIMATORS of tofu/plugin.h)",
        who));
  }
  api::Estimator* estimator =
      Guard(who, "tofu_create_estimator", [&] { return create(name.c_str()); });
  if (estimator == nullptr) {
    throw ClientError(fmt::format("{}: the library makes no estimator named \"{}\"", who, name));
  }
  return std::make_unique<PluginEstimator>(who, shared_from_this(), estimator, destroy);
}

std::unique_ptr<api::Controller> PluginLibrary::CreateController(const std::string& name) {
  const std::string who = fmt::format("plugin:{} ({})", name, path_.string());
  const auto create = Symbol<CreateControllerFn>(handle_, "tofu_create_controller");
  const auto destroy = Symbol<DestroyControllerFn>(handle_, "tofu_destroy_controller");
  if (create == nullptr || destroy == nullptr) {
    throw ClientError(fmt::format(
        "{}: the library makes no controllers (no tofu_create_controller and "
        "tofu_destroy_controller: TOFU_PLUGIN_CONTROLLERS of tofu/plugin.h)",
        who));
  }
  api::Controller* controller =
      Guard(who, "tofu_create_controller", [&] { return create(name.c_str()); });
  if (controller == nullptr) {
    throw ClientError(fmt::format("{}: the library makes no controller named \"{}\"", who, name));
  }
  return std::make_unique<PluginController>(who, shared_from_this(), controller, destroy);
}

}  // namespace tofu::interface
