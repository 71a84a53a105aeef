// The plug-in's entry points (include/tofu/plugin.h). tofu calls
// tofu_create_estimator(KEY) with the key of the scenario's `plugins:` map that names this
// library; a library with one estimator need not care what its user called it, so every
// name gets a ComplementaryFilter (README.md). The expression ignores `name` on purpose.

#include <tofu/plugin.h>

#include "complementary_filter.h"

TOFU_PLUGIN_DECLARE_VERSION()
TOFU_PLUGIN_ESTIMATORS(((void)name, new tofu_example::ComplementaryFilter))
// No TOFU_PLUGIN_CONTROLLERS: asked for a controller, tofu then says that the library
// makes none.
