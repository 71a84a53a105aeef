// libFuzzer target: what a client process writes to tofu (docs/INTERFACE.md), through the
// protocol's framing and every decoder, both encodings (fuzz/client_messages.h). The
// oracle differs from the file readers' (fuzz_support.h): the protocol's documented error
// is interface::ProtocolError, which DecodeClientMessages absorbs; any exception that
// escapes it is a finding.
#include <cstdint>
#include <exception>
#include <string>
#include <typeinfo>

#include "fuzz/client_messages.h"
#include "fuzz/fuzz_support.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string bytes = tofu::fuzz::InputText(data, size);
  try {
    (void)tofu::fuzz::DecodeClientMessages(bytes);
  } catch (const std::exception& e) {
    tofu::fuzz::Finding(std::string("exception other than interface::ProtocolError: ") +
                        typeid(e).name() + ": " + e.what());
  } catch (...) {
    tofu::fuzz::Finding("exception not derived from std::exception");
  }
  return 0;
}
