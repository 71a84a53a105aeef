#include "renders/image_io.h"

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <csetjmp>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>
#include <stdexcept>

#include <fmt/format.h>
#include <png.h>

#include "core/error.h"

extern char** environ;

namespace tofu::renders {
namespace fs = std::filesystem;

// ---- PNG ----

namespace {

struct PngFile {
  std::FILE* file = nullptr;
  ~PngFile() {
    if (file != nullptr) std::fclose(file);
  }
};

[[noreturn]] void PngError(png_structp png, png_const_charp message) {
  // libpng wants a non-returning handler; unwind to the setjmp in the caller.
  auto* text = static_cast<std::string*>(png_get_error_ptr(png));
  if (text != nullptr) *text = message;
  png_longjmp(png, 1);
}

void PngWarning(png_structp, png_const_charp) {}

}  // namespace

void WritePng(const fs::path& path, const Image& image) {
  if (image.width <= 0 || image.height <= 0 ||
      image.rgb.size() != static_cast<size_t>(3) * image.width * image.height) {
    throw std::runtime_error(fmt::format("cannot write {}: empty or inconsistent image", path.string()));
  }
  PngFile out;
  out.file = std::fopen(path.c_str(), "wb");
  if (out.file == nullptr) {
    throw core::IoError(fmt::format("cannot write {}: {}", path.string(), std::strerror(errno)));
  }
  std::string error;
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, &error, PngError, PngWarning);
  png_infop info = png != nullptr ? png_create_info_struct(png) : nullptr;
  if (png == nullptr || info == nullptr) {
    png_destroy_write_struct(&png, nullptr);
    throw std::runtime_error("libpng: out of memory");
  }
  std::vector<png_bytep> rows(static_cast<size_t>(image.height));
  for (int y = 0; y < image.height; ++y) rows[y] = const_cast<png_bytep>(image.Pixel(0, y));
  if (setjmp(png_jmpbuf(png)) != 0) {
    png_destroy_write_struct(&png, &info);
    std::fclose(out.file);
    out.file = nullptr;
    std::error_code ignored;
    fs::remove(path, ignored);
    throw core::IoError(fmt::format("cannot write {}: libpng: {}", path.string(), error));
  }
  png_init_io(png, out.file);
  png_set_IHDR(png, info, static_cast<png_uint_32>(image.width),
               static_cast<png_uint_32>(image.height), 8, PNG_COLOR_TYPE_RGB, PNG_INTERLACE_NONE,
               PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  png_set_rows(png, info, rows.data());
  png_write_png(png, info, PNG_TRANSFORM_IDENTITY, nullptr);
  png_destroy_write_struct(&png, &info);
  if (std::fflush(out.file) != 0 || std::ferror(out.file) != 0) {
    std::fclose(out.file);
    out.file = nullptr;
    std::error_code ignored;
    fs::remove(path, ignored);
    throw core::IoError(fmt::format("cannot write {}: {}", path.string(), std::strerror(errno)));
  }
}

Image ReadPng(const fs::path& path) {
  PngFile in;
  in.file = std::fopen(path.c_str(), "rb");
  if (in.file == nullptr) {
    throw std::runtime_error(fmt::format("cannot read {}: {}", path.string(), std::strerror(errno)));
  }
  std::string error;
  png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &error, PngError, PngWarning);
  png_infop info = png != nullptr ? png_create_info_struct(png) : nullptr;
  if (png == nullptr || info == nullptr) {
    png_destroy_read_struct(&png, nullptr, nullptr);
    throw std::runtime_error("libpng: out of memory");
  }
  Image image;
  if (setjmp(png_jmpbuf(png)) != 0) {
    png_destroy_read_struct(&png, &info, nullptr);
    throw std::runtime_error(fmt::format("cannot read {}: libpng: {}", path.string(), error));
  }
  png_init_io(png, in.file);
  png_read_png(png, info, PNG_TRANSFORM_STRIP_16 | PNG_TRANSFORM_STRIP_ALPHA | PNG_TRANSFORM_EXPAND,
               nullptr);
  const int channels = png_get_channels(png, info);
  image = Image(static_cast<int>(png_get_image_width(png, info)),
                static_cast<int>(png_get_image_height(png, info)));
  png_bytepp rows = png_get_rows(png, info);
  for (int y = 0; y < image.height; ++y) {
    for (int x = 0; x < image.width; ++x) {
      const png_bytep p = rows[y] + static_cast<size_t>(channels) * x;
      uint8_t* q = image.Pixel(x, y);
      q[0] = p[0];
      q[1] = channels >= 3 ? p[1] : p[0];
      q[2] = channels >= 3 ? p[2] : p[0];
    }
  }
  png_destroy_read_struct(&png, &info, nullptr);
  return image;
}

// ---- ffmpeg ----

std::string FindFfmpeg() {
  if (const char* env = std::getenv("TOFU_FFMPEG"); env != nullptr && *env != '\0') {
    return std::string(env) == "none" ? std::string() : std::string(env);
  }
  const char* path = std::getenv("PATH");
  std::stringstream dirs(path != nullptr ? path : "/usr/bin:/bin");
  std::string dir;
  while (std::getline(dirs, dir, ':')) {
    if (dir.empty()) continue;
    const fs::path candidate = fs::path(dir) / "ffmpeg";
    if (::access(candidate.c_str(), X_OK) == 0) return candidate.string();
  }
  return {};
}

namespace {

// Writes all of `data` to a pipe without dying of SIGPIPE if the reader has gone: the
// signal is blocked on this thread and a pending one is consumed before unblocking.
bool WriteAllToPipe(int fd, const uint8_t* data, size_t size) {
  sigset_t pipe_set;
  sigset_t old_set;
  sigemptyset(&pipe_set);
  sigaddset(&pipe_set, SIGPIPE);
  pthread_sigmask(SIG_BLOCK, &pipe_set, &old_set);
  bool ok = true;
  while (size > 0) {
    const ssize_t n = ::write(fd, data, size);
    if (n < 0) {
      if (errno == EINTR) continue;
      ok = false;
      break;
    }
    data += n;
    size -= static_cast<size_t>(n);
  }
  if (!ok) {
    const timespec zero{0, 0};
    while (sigtimedwait(&pipe_set, nullptr, &zero) > 0) {
    }
  }
  pthread_sigmask(SIG_SETMASK, &old_set, nullptr);
  return ok;
}

std::string LastLines(const fs::path& path, size_t max_chars) {
  std::ifstream in(path);
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  while (!text.empty() && (text.back() == '\n' || text.back() == '\r')) text.pop_back();
  if (text.size() > max_chars) text = "..." + text.substr(text.size() - max_chars);
  return text.empty() ? std::string("(no message)") : text;
}

// ---- GIF (fall-back when ffmpeg is missing) ----

// Palette: a 6 x 7 x 6 colour cube (252 entries; green gets the extra level, the eye is
// most sensitive to it), padded to 256.
constexpr int kLevelsR = 6;
constexpr int kLevelsG = 7;
constexpr int kLevelsB = 6;

uint8_t Quantise(uint8_t value, int levels, int threshold_16) {
  // Ordered dithering: the Bayer threshold shifts the value by up to one step.
  const int step = 255 / (levels - 1);
  const int v = value + (threshold_16 - 8) * step / 16;
  const int q = (std::clamp(v, 0, 255) * (levels - 1) + 127) / 255;
  return static_cast<uint8_t>(q);
}

class GifWriter {
 public:
  GifWriter(const fs::path& path, int width, int height, int delay_cs)
      : out_(path, std::ios::binary), width_(width), height_(height), delay_cs_(delay_cs) {
    if (!out_) throw core::IoError(fmt::format("cannot write {}", path.string()));
    Bytes("GIF89a");
    Word(width);
    Word(height);
    Byte(0xF7);  // global colour table, 8 bits per primary, 256 entries
    Byte(0);     // background colour
    Byte(0);     // aspect ratio
    for (int i = 0; i < 256; ++i) {
      const int r = i / (kLevelsG * kLevelsB);
      const int g = (i / kLevelsB) % kLevelsG;
      const int b = i % kLevelsB;
      const bool used = i < kLevelsR * kLevelsG * kLevelsB;
      Byte(used ? static_cast<uint8_t>(r * 255 / (kLevelsR - 1)) : 0);
      Byte(used ? static_cast<uint8_t>(g * 255 / (kLevelsG - 1)) : 0);
      Byte(used ? static_cast<uint8_t>(b * 255 / (kLevelsB - 1)) : 0);
    }
    // Netscape extension: loop forever.
    Bytes("\x21\xFF\x0BNETSCAPE2.0");
    Byte(3);
    Byte(1);
    Word(0);
    Byte(0);
  }

  void Add(const Image& frame) {
    static constexpr int kBayer4[4][4] = {{0, 8, 2, 10}, {12, 4, 14, 6}, {3, 11, 1, 9}, {15, 7, 13, 5}};
    std::vector<uint8_t> indices(static_cast<size_t>(width_) * height_);
    for (int y = 0; y < height_; ++y) {
      for (int x = 0; x < width_; ++x) {
        const uint8_t* p = frame.Pixel(x, y);
        const int t = kBayer4[y & 3][x & 3];
        indices[static_cast<size_t>(y) * width_ + x] = static_cast<uint8_t>(
            (Quantise(p[0], kLevelsR, t) * kLevelsG + Quantise(p[1], kLevelsG, t)) * kLevelsB +
            Quantise(p[2], kLevelsB, t));
      }
    }
    // Graphic control extension: the frame's delay.
    Bytes("\x21\xF9\x04");
    Byte(0x04);  // disposal: leave in place
    Word(delay_cs_);
    Byte(0);
    Byte(0);
    // Image descriptor, full frame, no local table.
    Byte(0x2C);
    Word(0);
    Word(0);
    Word(width_);
    Word(height_);
    Byte(0);
    Lzw(indices);
  }

  void Finish() {
    Byte(0x3B);
    out_.close();
    if (!out_) throw std::runtime_error("GIF: write failed");
  }

 private:
  void Byte(uint8_t b) { out_.put(static_cast<char>(b)); }
  void Word(int w) {
    Byte(static_cast<uint8_t>(w & 0xFF));
    Byte(static_cast<uint8_t>((w >> 8) & 0xFF));
  }
  void Bytes(const char* s) { out_.write(s, static_cast<std::streamsize>(std::strlen(s))); }

  // Variable-width LZW (GIF flavour: minimum code size 8, codes up to 12 bits, a clear
  // code when the table is full), packed LSB first into sub-blocks of <= 255 bytes.
  void Lzw(const std::vector<uint8_t>& indices) {
    constexpr int kMinCodeSize = 8;
    constexpr int kClear = 1 << kMinCodeSize;
    constexpr int kEnd = kClear + 1;
    constexpr int kMaxCode = 4095;
    constexpr int kHashSize = 8192;  // open addressing, > 4096 entries
    std::vector<int32_t> hash_key(kHashSize, -1);
    std::vector<int16_t> hash_code(kHashSize, 0);
    std::vector<uint8_t> block;
    uint32_t bit_buffer = 0;
    int bit_count = 0;
    int code_size = kMinCodeSize + 1;
    int next_code = kEnd + 1;

    const auto flush_block = [&](bool all) {
      while (block.size() >= 255 || (all && !block.empty())) {
        const size_t n = std::min<size_t>(255, block.size());
        Byte(static_cast<uint8_t>(n));
        out_.write(reinterpret_cast<const char*>(block.data()), static_cast<std::streamsize>(n));
        block.erase(block.begin(), block.begin() + static_cast<std::ptrdiff_t>(n));
      }
    };
    const auto emit = [&](int code) {
      bit_buffer |= static_cast<uint32_t>(code) << bit_count;
      bit_count += code_size;
      while (bit_count >= 8) {
        block.push_back(static_cast<uint8_t>(bit_buffer & 0xFF));
        bit_buffer >>= 8;
        bit_count -= 8;
      }
      if (block.size() >= 255) flush_block(false);
    };
    const auto reset_table = [&]() {
      std::fill(hash_key.begin(), hash_key.end(), -1);
      code_size = kMinCodeSize + 1;
      next_code = kEnd + 1;
    };

    Byte(kMinCodeSize);
    emit(kClear);
    int prefix = indices.empty() ? -1 : indices[0];
    for (size_t i = 1; i < indices.size(); ++i) {
      const int c = indices[i];
      const int32_t key = (prefix << 8) | c;
      int slot = static_cast<int>((static_cast<uint32_t>(key) * 2654435761u) >> 19) & (kHashSize - 1);
      while (hash_key[slot] != -1 && hash_key[slot] != key) slot = (slot + 1) & (kHashSize - 1);
      if (hash_key[slot] == key) {
        prefix = hash_code[slot];
        continue;
      }
      emit(prefix);
      if (next_code <= kMaxCode) {
        hash_key[slot] = key;
        hash_code[slot] = static_cast<int16_t>(next_code);
        // The decoder widens its codes once the next code no longer fits.
        if (next_code == (1 << code_size) && code_size < 12) ++code_size;
        ++next_code;
      } else {
        emit(kClear);
        reset_table();
      }
      prefix = c;
    }
    if (prefix >= 0) emit(prefix);
    emit(kEnd);
    if (bit_count > 0) block.push_back(static_cast<uint8_t>(bit_buffer & 0xFF));
    flush_block(true);
    Byte(0);  // block terminator
  }

  std::ofstream out_;
  int width_;
  int height_;
  int delay_cs_;
};

}  // namespace

struct ClipWriter::Impl {
  int width = 0;
  int height = 0;
  int fps = 30;
  fs::path path;
  // MP4
  pid_t pid = -1;
  int pipe_fd = -1;
  fs::path log_path;
  bool pipe_broken = false;
  // GIF
  std::unique_ptr<GifWriter> gif;
  bool gif_mode = false;
  int gif_stride = 1;
  int64_t frame_index = 0;

  void StartFfmpeg(const std::string& ffmpeg) {
    int fds[2];
    if (::pipe(fds) != 0) throw std::runtime_error("cannot create a pipe to ffmpeg");
    ::fcntl(fds[1], F_SETFD, FD_CLOEXEC);
    log_path = path.string() + ".ffmpeg.log";
    const std::string size = fmt::format("{}x{}", width, height);
    const std::string rate = fmt::format("{}", fps);
    // Deterministic output: single-threaded x264, no encoder tag or metadata, even
    // dimensions for yuv420p.
    std::vector<std::string> args = {ffmpeg, "-hide_banner", "-loglevel", "error", "-y",
                                     "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", size,
                                     "-framerate", rate, "-i", "pipe:0", "-an",
                                     "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2",
                                     "-c:v", "libx264", "-preset", "veryfast", "-crf", "23",
                                     "-pix_fmt", "yuv420p", "-threads", "1",
                                     "-fflags", "+bitexact", "-flags:v", "+bitexact",
                                     "-map_metadata", "-1", "-movflags", "+faststart",
                                     path.string()};
    std::vector<char*> argv;
    for (std::string& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_adddup2(&actions, fds[0], STDIN_FILENO);
    posix_spawn_file_actions_addclose(&actions, fds[0]);
    posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, "/dev/null", O_WRONLY, 0);
    posix_spawn_file_actions_addopen(&actions, STDERR_FILENO, log_path.c_str(),
                                     O_WRONLY | O_CREAT | O_TRUNC, 0644);
    const int rc = posix_spawn(&pid, ffmpeg.c_str(), &actions, nullptr, argv.data(), environ);
    posix_spawn_file_actions_destroy(&actions);
    ::close(fds[0]);
    if (rc != 0) {
      ::close(fds[1]);
      pid = -1;
      throw std::runtime_error(fmt::format("cannot start {}: {}", ffmpeg, std::strerror(rc)));
    }
    pipe_fd = fds[1];
  }

  int WaitFfmpeg() {
    if (pipe_fd >= 0) {
      ::close(pipe_fd);
      pipe_fd = -1;
    }
    if (pid < 0) return 0;
    int status = 0;
    while (::waitpid(pid, &status, 0) < 0 && errno == EINTR) {
    }
    pid = -1;
    return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  }
};

ClipWriter::ClipWriter(const fs::path& stem, int width, int height, int fps,
                       const std::string& ffmpeg)
    : impl_(std::make_unique<Impl>()) {
  if (width <= 0 || height <= 0 || fps <= 0) throw std::runtime_error("clip: bad size or rate");
  impl_->width = width;
  impl_->height = height;
  impl_->fps = fps;
  if (!ffmpeg.empty()) {
    impl_->path = stem.string() + ".mp4";
    impl_->StartFfmpeg(ffmpeg);
  } else {
    impl_->path = stem.string() + ".gif";
    impl_->gif_mode = true;
    impl_->gif_stride = (fps + 9) / 10;  // at most 10 frames per second
    const int delay_cs = std::max(2, (100 * impl_->gif_stride + fps / 2) / fps);
    impl_->gif = std::make_unique<GifWriter>(impl_->path, width, height, delay_cs);
  }
}

ClipWriter::~ClipWriter() {
  if (impl_ && impl_->pid >= 0) impl_->WaitFfmpeg();
}

bool ClipWriter::is_mp4() const { return !impl_->gif_mode; }

void ClipWriter::Add(const Image& frame) {
  if (frame.width != impl_->width || frame.height != impl_->height) {
    throw std::runtime_error("clip: frame size differs from the clip's");
  }
  if (impl_->gif) {
    if (impl_->frame_index++ % impl_->gif_stride == 0) impl_->gif->Add(frame);
    return;
  }
  if (impl_->pipe_broken) return;
  if (!WriteAllToPipe(impl_->pipe_fd, frame.rgb.data(), frame.rgb.size())) impl_->pipe_broken = true;
}

fs::path ClipWriter::Finish() {
  if (impl_->gif_mode) {
    if (!impl_->gif) return impl_->path;
    impl_->gif->Finish();
    impl_->gif.reset();
    return impl_->path;
  }
  const int status = impl_->WaitFfmpeg();
  std::error_code ignored;
  if (status != 0 || impl_->pipe_broken) {
    const std::string message = LastLines(impl_->log_path, 400);
    fs::remove(impl_->log_path, ignored);
    fs::remove(impl_->path, ignored);
    throw std::runtime_error(
        fmt::format("ffmpeg failed (exit {}) writing {}: {}", status, impl_->path.string(), message));
  }
  fs::remove(impl_->log_path, ignored);
  return impl_->path;
}

}  // namespace tofu::renders
