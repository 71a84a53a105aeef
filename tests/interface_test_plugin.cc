// A C++ plug-in for tests/interface_test.cc, built three times (tests/CMakeLists.txt): as
// it should be, reporting another API version (TOFU_TEST_PLUGIN_WRONG_VERSION), and
// without the version entry point (TOFU_TEST_PLUGIN_NO_VERSION).
#include <stdexcept>
#include <string>
#include <string_view>

#include "tofu/plugin.h"

namespace {

// One estimate per measurement, at its stamp.
class Echo final : public tofu::api::Estimator {
 public:
  void Start(const tofu::api::EstimatorSetup& setup) override { method_ = setup.method; }
  void Add(const tofu::api::Measurement& m, std::vector<tofu::api::Estimate>* out) override {
    tofu::api::Estimate e;
    e.t_ns = m.t_ns;
    e.valid = true;
    out->push_back(e);
    ++adds_;
  }
  std::string ReportJson() const override {
    return "{\"adds\": " + std::to_string(adds_) + ", \"method\": \"" + method_ + "\"}";
  }

 private:
  std::string method_;
  int adds_ = 0;
};

// Fails on its third sample.
class Thrower final : public tofu::api::Estimator {
 public:
  void Start(const tofu::api::EstimatorSetup&) override {}
  void Add(const tofu::api::Measurement& m, std::vector<tofu::api::Estimate>*) override {
    if (++adds_ == 3) throw std::runtime_error("filter diverged at t_ns " + std::to_string(m.t_ns));
  }

 private:
  int adds_ = 0;
};

// Holds its weight.
class Hover final : public tofu::api::Controller {
 public:
  void Start(const tofu::api::ControllerSetup& setup) override {
    weight_N_ = setup.mass_kg * setup.gravity_mps2;
  }
  tofu::api::ControlCommand Compute(const tofu::api::ControlState&,
                                    const tofu::api::ControlReference&) override {
    tofu::api::ControlCommand command;
    command.force_B_N = {0.0, 0.0, weight_N_};
    return command;
  }

 private:
  double weight_N_ = 0.0;
};

}  // namespace

#if defined(TOFU_TEST_PLUGIN_WRONG_VERSION)
TOFU_PLUGIN_EXPORT int tofu_plugin_api_version(void) { return TOFU_PLUGIN_API_VERSION + 1; }
#elif !defined(TOFU_TEST_PLUGIN_NO_VERSION)
TOFU_PLUGIN_DECLARE_VERSION()
#endif

TOFU_PLUGIN_ESTIMATORS(std::string_view(name) == "echo"      ? static_cast<tofu::api::Estimator*>(new Echo)
                       : std::string_view(name) == "thrower" ? new Thrower
                                                             : nullptr)
TOFU_PLUGIN_CONTROLLERS(std::string_view(name) == "hover" ? new Hover : nullptr)
