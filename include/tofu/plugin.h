#pragma once
// A C++ plug-in: a shared library that tofu loads with dlopen when a scenario names it
//   plugins: {my_ekf: {library: path/to/libmy_ekf.so, config: {...}}}
//   estimation: {methods: [consensus, "plugin:my_ekf"]}
// and asks for estimators (or controllers) by that name. The library defines, with the
// macros below, three C functions:
//   int tofu_plugin_api_version(void);               the TOFU_API_VERSION it was built with
//   tofu::api::Estimator* tofu_create_estimator(const char* name);     or nullptr
//   tofu::api::Controller* tofu_create_controller(const char* name);   or nullptr
// tofu refuses a library whose version differs from its own, naming both. The objects
// are destroyed by the library that made them (tofu_destroy_*), so a plug-in may use its
// own allocator. C++ classes cross the boundary: build the plug-in with the same
// compiler family and standard library as tofu (GCC's libstdc++ on Debian), as for any
// C++ plug-in API (Gazebo's, ROS's pluginlib).

#include "tofu/api.h"

#define TOFU_PLUGIN_API_VERSION TOFU_API_VERSION
#define TOFU_PLUGIN_EXPORT extern "C" __attribute__((visibility("default")))

/// Defines the version entry point; use once per library.
#define TOFU_PLUGIN_DECLARE_VERSION() \
  TOFU_PLUGIN_EXPORT int tofu_plugin_api_version(void) { return TOFU_PLUGIN_API_VERSION; }

/// Defines the estimator entry points: `make` is an expression of `name` (const char*)
/// that returns a new tofu::api::Estimator* or nullptr for a name it does not know.
#define TOFU_PLUGIN_ESTIMATORS(make)                                                   \
  TOFU_PLUGIN_EXPORT tofu::api::Estimator* tofu_create_estimator(const char* name) {   \
    return (make);                                                                     \
  }                                                                                    \
  TOFU_PLUGIN_EXPORT void tofu_destroy_estimator(tofu::api::Estimator* estimator) {    \
    delete estimator;                                                                  \
  }

/// Defines the controller entry points, as TOFU_PLUGIN_ESTIMATORS.
#define TOFU_PLUGIN_CONTROLLERS(make)                                                  \
  TOFU_PLUGIN_EXPORT tofu::api::Controller* tofu_create_controller(const char* name) { \
    return (make);                                                                     \
  }                                                                                    \
  TOFU_PLUGIN_EXPORT void tofu_destroy_controller(tofu::api::Controller* controller) { \
    delete controller;                                                                 \
  }
