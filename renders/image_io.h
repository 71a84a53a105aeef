#pragma once
// Pixels out: PNG files (libpng) and clips, MP4 through Debian's ffmpeg (frames piped as
// raw RGB) or, when ffmpeg is missing, an animated GIF written here. Every encoder is
// deterministic: the same frames give the same bytes (no time stamps, no encoder
// version in the container, single-threaded x264).

#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

namespace tofu::renders {

/// An 8-bit RGB image, rows top to bottom.
struct Image {
  int width = 0;
  int height = 0;
  std::vector<uint8_t> rgb;  ///< 3 * width * height

  Image() = default;
  Image(int w, int h) : width(w), height(h), rgb(static_cast<size_t>(3) * w * h, 0) {}
  uint8_t* Pixel(int x, int y) { return rgb.data() + 3 * (static_cast<size_t>(y) * width + x); }
  const uint8_t* Pixel(int x, int y) const {
    return rgb.data() + 3 * (static_cast<size_t>(y) * width + x);
  }
};

/// Writes `image` as an 8-bit RGB PNG (no time chunk). Throws std::runtime_error on an I/O
/// or encoder failure (a partial file is removed).
void WritePng(const std::filesystem::path& path, const Image& image);

/// Reads an 8-bit RGB PNG (tests, gallery checks). Throws std::runtime_error.
Image ReadPng(const std::filesystem::path& path);

/// The ffmpeg executable used for MP4 clips: $TOFU_FFMPEG if set ("none" disables ffmpeg:
/// GIF clips), else the first `ffmpeg` on $PATH; empty when there is none.
std::string FindFfmpeg();

/// A clip being written: MP4 via ffmpeg (H.264, yuv420p, CRF 23) or a GIF fall-back
/// (6x7x6 colour cube with ordered dithering, at most 10 frames per second: frames are
/// skipped above that). Frames must all have the clip's size.
class ClipWriter {
 public:
  /// `stem`: the path without extension; the writer appends ".mp4" or ".gif".
  /// Throws std::runtime_error if the output cannot be opened or ffmpeg cannot start.
  ClipWriter(const std::filesystem::path& stem, int width, int height, int fps,
             const std::string& ffmpeg = FindFfmpeg());
  ~ClipWriter();
  ClipWriter(const ClipWriter&) = delete;
  ClipWriter& operator=(const ClipWriter&) = delete;

  void Add(const Image& frame);
  /// Finishes the file and returns its path. Throws std::runtime_error when ffmpeg failed
  /// (its last message included).
  std::filesystem::path Finish();
  bool is_mp4() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tofu::renders
