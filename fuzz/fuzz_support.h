#pragma once
// Shared by the libFuzzer targets of fuzz/ (docs/FUZZING.md). Header-only: each target is
// one translation unit plus this.
//
// The oracle of every target: a reader either returns or throws core::InputError, the
// project's one documented exception for bad input (DESIGN.md, "Errors"), and that error
// names the input file (SourceLocation::file). Anything else is a finding: another
// exception (reported here, then abort()), a crash, a sanitizer report, a timeout or an
// out-of-memory (reported by libFuzzer).
//
// Targets that read files write the input into a scratch directory created once per
// process under $TMPDIR (scripts/fuzz.sh points it to /dev/shm) and removed at exit;
// nothing is written anywhere else.

#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <fstream>
#include <string>
#include <string_view>
#include <system_error>
#include <typeinfo>

#include "core/error.h"

namespace tofu::fuzz {

/// The fuzz input as text (bytes as they are, NULs included).
inline std::string InputText(const uint8_t* data, size_t size) {
  return std::string(reinterpret_cast<const char*>(data), size);
}

[[noreturn]] inline void Finding(const std::string& what) {
  std::fprintf(stderr, "\n==tofu-fuzz== FINDING: %s\n", what.c_str());
  std::fflush(stderr);
  std::abort();
}

/// Runs `read`; returns true if it returned, false if it threw core::InputError naming a
/// file; any other outcome is a finding.
template <class Read>
bool ParsesOrInputError(Read&& read) {
  try {
    read();
    return true;
  } catch (const core::InputError& e) {
    if (e.location().file.empty()) {
      Finding(std::string("core::InputError that names no file: ") + e.what());
    }
    return false;
  } catch (const std::exception& e) {
    Finding(std::string("exception other than core::InputError: ") + typeid(e).name() + ": " +
            e.what());
  } catch (...) {
    Finding("exception not derived from std::exception");
  }
}

/// A directory of this process, created on first use under $TMPDIR (else /tmp) and
/// removed when the process exits normally.
class ScratchDir {
 public:
  static const std::filesystem::path& Path() {
    static ScratchDir dir;
    return dir.path_;
  }

 private:
  ScratchDir() {
    const char* tmp = std::getenv("TMPDIR");
    std::string pattern =
        (std::filesystem::path(tmp != nullptr && *tmp != '\0' ? tmp : "/tmp") / "tofu-fuzz-XXXXXX")
            .string();
    if (mkdtemp(pattern.data()) == nullptr) Finding("cannot create a scratch directory " + pattern);
    path_ = pattern;
  }
  ~ScratchDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  std::filesystem::path path_;
};

/// Writes `bytes` to `path` (parents created), replacing it.
inline void WriteFile(const std::filesystem::path& path, std::string_view bytes) {
  std::error_code ec;
  std::filesystem::create_directories(path.parent_path(), ec);
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  out.close();
  if (!out) Finding("cannot write the scratch file " + path.string());
}

}  // namespace tofu::fuzz
