// tofu's own estimation methods as a C++ plug-in (include/tofu/plugin.h): the lossless
// check of the plug-in path. A scenario names it as a user's library,
//   plugins: {consensus_plugin: {library: .../libtofu_builtin_plugin.so, config: {method: consensus}}}
// and its estimates must be byte-identical to the in-process method's.

#include "harness/hosted_builtin.h"
#include "tofu/plugin.h"

TOFU_PLUGIN_DECLARE_VERSION()
TOFU_PLUGIN_ESTIMATORS((static_cast<void>(name), new tofu::harness::HostedBuiltinEstimator(std::nullopt)))
