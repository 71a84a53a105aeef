// libFuzzer target: the corpus spec reader, corpus::ParseCorpusSpec (corpora/*.yaml). A
// spec that loads has planned episode 0 and validated its scenario (corpus_spec.h).
#include <string>

#include "corpus/corpus_spec.h"
#include "fuzz/fuzz_support.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text = tofu::fuzz::InputText(data, size);
  tofu::fuzz::ParsesOrInputError(
      [&] { (void)tofu::corpus::ParseCorpusSpec(text, "fuzz_corpus.yaml"); });
  return 0;
}
