#include "renders/render_options.h"

#include "core/error.h"

namespace tofu::renders {

void ThrowInvalidRenderOptions(const std::string& why) {
  const std::size_t colon = why.find(": ");
  if (colon == std::string::npos) throw core::InputError({"render options"}, "", why);
  throw core::InputError({"render options"}, why.substr(0, colon), why.substr(colon + 2));
}

}  // namespace tofu::renders
