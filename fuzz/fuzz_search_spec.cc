// libFuzzer target: the search spec reader, campaign::ParseSearchSpec (searches/*.yaml). Its
// base is read relative to tests/data/search (dropout_base.yaml, client_base.yaml); a spec
// that loads has decoded its space's corners into scenarios that load (search_spec.h).
#include <string>

#include "campaign/search_spec.h"
#include "fuzz/fuzz_support.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text = tofu::fuzz::InputText(data, size);
  tofu::fuzz::ParsesOrInputError(
      [&] { (void)tofu::campaign::ParseSearchSpec(text, "fuzz_search.yaml", TOFU_FUZZ_SEARCH_DIR); });
  return 0;
}
