#pragma once
// A thin RAII layer over the HDF5 C library (libhdf5 from Debian) for the corpus writer
// and verifier: files, groups, 1-D/2-D datasets of int64, uint32, uint8 and double,
// chunked and compressed (shuffle + deflate) so that a corpus stays small, variable-length
// string datasets, and string/number attributes. Objects carry no modification times
// (H5Pset_obj_track_times off): the same episode gives the same bytes, whatever the day.
// Every HDF5 failure is a core::IoError naming the file and the object.

#include <hdf5.h>

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace tofu::corpus {

/// An owned HDF5 identifier, closed with the function matching its type.
class Hdf5Id {
 public:
  Hdf5Id() = default;
  explicit Hdf5Id(hid_t id) : id_(id) {}
  ~Hdf5Id();
  Hdf5Id(Hdf5Id&& other) noexcept : id_(other.id_) { other.id_ = -1; }
  Hdf5Id& operator=(Hdf5Id&& other) noexcept;
  Hdf5Id(const Hdf5Id&) = delete;
  Hdf5Id& operator=(const Hdf5Id&) = delete;
  hid_t get() const { return id_; }
  bool valid() const { return id_ >= 0; }

 private:
  hid_t id_ = -1;
};

/// A group (or a file's root group) to write into or read from.
class Hdf5Group {
 public:
  Hdf5Group() = default;
  Hdf5Group(Hdf5Id id, std::string path, std::string file)
      : id_(std::move(id)), path_(std::move(path)), file_(std::move(file)) {}
  hid_t id() const { return id_.get(); }
  const std::string& path() const { return path_; }
  const std::string& file() const { return file_; }

  Hdf5Group CreateGroup(const std::string& name) const;
  Hdf5Group OpenGroup(const std::string& name) const;
  bool Has(const std::string& name) const;
  /// Names of the links in this group, sorted.
  std::vector<std::string> Children() const;

  /// A dataset of `rows` x `columns` (columns = 0: 1-D), chunked along rows and
  /// compressed (shuffle + deflate level 4) when it holds more than a few values.
  void WriteInt64(const std::string& name, const std::vector<std::int64_t>& data, std::size_t columns = 0) const;
  void WriteUInt32(const std::string& name, const std::vector<std::uint32_t>& data, std::size_t columns = 0) const;
  void WriteUInt8(const std::string& name, const std::vector<std::uint8_t>& data, std::size_t columns = 0) const;
  void WriteDouble(const std::string& name, const std::vector<double>& data, std::size_t columns = 0) const;
  /// A 1-D dataset of variable-length UTF-8 strings.
  void WriteStrings(const std::string& name, const std::vector<std::string>& data) const;

  std::vector<std::int64_t> ReadInt64(const std::string& name) const;
  std::vector<std::uint32_t> ReadUInt32(const std::string& name) const;
  std::vector<std::uint8_t> ReadUInt8(const std::string& name) const;
  std::vector<double> ReadDouble(const std::string& name) const;
  std::vector<std::string> ReadStrings(const std::string& name) const;
  /// Dimensions of a dataset.
  std::vector<std::size_t> Shape(const std::string& name) const;

  /// FNV-1a (64 bit) over every dataset below this group, in sorted path order: its
  /// path, shape and values (strings as their UTF-8 bytes, each followed by NUL).
  /// Attributes are not included (they hold the tofu version and commit). A content
  /// fingerprint, not a cryptographic hash.
  std::uint64_t ContentHash() const;

  /// Attributes on this group (UTF-8 strings, int64, double).
  void SetAttribute(const std::string& name, const std::string& value) const;
  void SetAttribute(const std::string& name, std::int64_t value) const;
  void SetAttribute(const std::string& name, double value) const;
  /// Attributes on a dataset of this group.
  void SetDatasetAttribute(const std::string& dataset, const std::string& name, const std::string& value) const;
  std::string StringAttribute(const std::string& name) const;
  std::int64_t Int64Attribute(const std::string& name) const;
  double DoubleAttribute(const std::string& name) const;
  bool HasAttribute(const std::string& name) const;

 private:
  void Write(const std::string& name, hid_t type, const void* data, std::size_t count, std::size_t columns) const;
  template <typename T>
  std::vector<T> Read(const std::string& name, hid_t type) const;
  Hdf5Id id_;
  std::string path_;
  std::string file_;
};

class Hdf5File {
 public:
  /// Creates (truncating) or opens read-only. Throws core::IoError.
  static Hdf5File Create(const std::filesystem::path& path);
  static Hdf5File OpenReadOnly(const std::filesystem::path& path);
  /// The root group.
  const Hdf5Group& root() const { return root_; }
  /// Copies group `source_path` of `source` (recursively, with attributes) to `dest_path`
  /// of this file (H5Ocopy).
  void CopyFrom(const Hdf5File& source, const std::string& source_path, const std::string& dest_path) const;
  /// Flushes and closes; throws core::IoError if HDF5 reports a failure.
  void Close();
  const std::string& path() const { return path_; }
  hid_t id() const { return file_.get(); }

 private:
  Hdf5File(Hdf5Id file, std::string path);
  std::string path_;
  Hdf5Id file_;
  Hdf5Group root_;
};

}  // namespace tofu::corpus
