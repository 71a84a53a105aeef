#pragma once
// Private to renders/: the options of a render checked at the boundary. Each options
// struct says what is wrong with it through IsValid (the options convention of
// core/option_fields.h: "<option>: <problem>"); a render refuses bad options as the
// user's error (core::InputError at "render options", the option named as on the CLI).

#include <string>

namespace tofu::renders {

/// Throws core::InputError({"render options"}, <option>, <problem>) for IsValid's `why`.
[[noreturn]] void ThrowInvalidRenderOptions(const std::string& why);

/// `options` if options.IsValid(), else ThrowInvalidRenderOptions.
template <typename Options>
const Options& RequireValidRenderOptions(const Options& options) {
  std::string why;
  if (!options.IsValid(&why)) ThrowInvalidRenderOptions(why);
  return options;
}

}  // namespace tofu::renders
