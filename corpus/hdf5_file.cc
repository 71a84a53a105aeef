#include "corpus/hdf5_file.h"

#include <algorithm>

#include <fmt/format.h>

#include "core/error.h"

namespace tofu::corpus {
namespace {

// Rows per chunk: ~64 KiB of doubles for a 1-D dataset, fewer rows for wider ones.
constexpr std::size_t kChunkValues = 8192;
// Below this many values a dataset is stored contiguous (a chunk's overhead costs more).
constexpr std::size_t kMinCompressedValues = 64;
constexpr unsigned kDeflateLevel = 4;

[[noreturn]] void Fail(const std::string& file, const std::string& what) {
  throw core::IoError(fmt::format("HDF5 {}: {}", file, what));
}

// HDF5 prints its error stack to stderr by default; tofu reports its own message.
struct SilenceHdf5 {
  SilenceHdf5() { H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr); }
};
const SilenceHdf5 kSilence;


}  // namespace

Hdf5Id::~Hdf5Id() {
  if (id_ < 0) return;
  switch (H5Iget_type(id_)) {
    case H5I_FILE: H5Fclose(id_); break;
    case H5I_GROUP: H5Gclose(id_); break;
    case H5I_DATASET: H5Dclose(id_); break;
    case H5I_DATASPACE: H5Sclose(id_); break;
    case H5I_DATATYPE: H5Tclose(id_); break;
    case H5I_ATTR: H5Aclose(id_); break;
    case H5I_GENPROP_LST: H5Pclose(id_); break;
    default: break;
  }
}

Hdf5Id& Hdf5Id::operator=(Hdf5Id&& other) noexcept {
  if (this != &other) {
    Hdf5Id discard(id_);
    id_ = other.id_;
    other.id_ = -1;
  }
  return *this;
}

Hdf5Group Hdf5Group::CreateGroup(const std::string& name) const {
  Hdf5Id plist(H5Pcreate(H5P_GROUP_CREATE));
  H5Pset_obj_track_times(plist.get(), false);
  // Links in creation order make the file's layout follow the writer's order.
  Hdf5Id id(H5Gcreate2(id_.get(), name.c_str(), H5P_DEFAULT, plist.get(), H5P_DEFAULT));
  if (!id.valid()) Fail(file_, fmt::format("cannot create group {}/{}", path_, name));
  return Hdf5Group(std::move(id), path_ == "/" ? "/" + name : path_ + "/" + name, file_);
}

Hdf5Group Hdf5Group::OpenGroup(const std::string& name) const {
  Hdf5Id id(H5Gopen2(id_.get(), name.c_str(), H5P_DEFAULT));
  if (!id.valid()) Fail(file_, fmt::format("no group {}/{}", path_, name));
  return Hdf5Group(std::move(id), path_ == "/" ? "/" + name : path_ + "/" + name, file_);
}

bool Hdf5Group::Has(const std::string& name) const {
  return H5Lexists(id_.get(), name.c_str(), H5P_DEFAULT) > 0;
}

std::vector<std::string> Hdf5Group::Children() const {
  std::vector<std::string> names;
  H5Literate(
      id_.get(), H5_INDEX_NAME, H5_ITER_INC, nullptr,
      [](hid_t, const char* link, const H5L_info_t*, void* out) -> herr_t {
        static_cast<std::vector<std::string>*>(out)->emplace_back(link);
        return 0;
      },
      &names);
  std::sort(names.begin(), names.end());
  return names;
}

void Hdf5Group::Write(const std::string& name, hid_t type, const void* data, std::size_t count,
                      std::size_t columns) const {
  const std::size_t cols = std::max<std::size_t>(columns, 1);
  if (count % cols != 0) Fail(file_, fmt::format("{}/{}: {} values are not rows of {}", path_, name, count, cols));
  const hsize_t rows = count / cols;
  const hsize_t dims[2] = {rows, cols};
  const int rank = columns == 0 ? 1 : 2;
  Hdf5Id space(H5Screate_simple(rank, dims, nullptr));
  Hdf5Id create(H5Pcreate(H5P_DATASET_CREATE));
  H5Pset_obj_track_times(create.get(), false);
  if (count >= kMinCompressedValues) {
    const hsize_t chunk[2] = {std::max<hsize_t>(1, std::min<hsize_t>(rows, kChunkValues / cols)), cols};
    H5Pset_chunk(create.get(), rank, chunk);
    H5Pset_shuffle(create.get());
    H5Pset_deflate(create.get(), kDeflateLevel);
  }
  Hdf5Id dataset(H5Dcreate2(id_.get(), name.c_str(), type, space.get(), H5P_DEFAULT, create.get(), H5P_DEFAULT));
  if (!dataset.valid()) Fail(file_, fmt::format("cannot create dataset {}/{}", path_, name));
  if (count > 0 && H5Dwrite(dataset.get(), type, H5S_ALL, H5S_ALL, H5P_DEFAULT, data) < 0) {
    Fail(file_, fmt::format("cannot write dataset {}/{}", path_, name));
  }
}

void Hdf5Group::WriteInt64(const std::string& name, const std::vector<std::int64_t>& data, std::size_t columns) const {
  Write(name, H5T_NATIVE_INT64, data.data(), data.size(), columns);
}
void Hdf5Group::WriteUInt32(const std::string& name, const std::vector<std::uint32_t>& data, std::size_t columns) const {
  Write(name, H5T_NATIVE_UINT32, data.data(), data.size(), columns);
}
void Hdf5Group::WriteUInt8(const std::string& name, const std::vector<std::uint8_t>& data, std::size_t columns) const {
  Write(name, H5T_NATIVE_UINT8, data.data(), data.size(), columns);
}
void Hdf5Group::WriteDouble(const std::string& name, const std::vector<double>& data, std::size_t columns) const {
  Write(name, H5T_NATIVE_DOUBLE, data.data(), data.size(), columns);
}

void Hdf5Group::WriteStrings(const std::string& name, const std::vector<std::string>& data) const {
  Hdf5Id type(H5Tcopy(H5T_C_S1));
  H5Tset_size(type.get(), H5T_VARIABLE);
  H5Tset_cset(type.get(), H5T_CSET_UTF8);
  std::vector<const char*> pointers;
  for (const std::string& s : data) pointers.push_back(s.c_str());
  const hsize_t dims[1] = {data.size()};
  Hdf5Id space(H5Screate_simple(1, dims, nullptr));
  Hdf5Id create(H5Pcreate(H5P_DATASET_CREATE));
  H5Pset_obj_track_times(create.get(), false);
  Hdf5Id dataset(H5Dcreate2(id_.get(), name.c_str(), type.get(), space.get(), H5P_DEFAULT, create.get(), H5P_DEFAULT));
  if (!dataset.valid()) Fail(file_, fmt::format("cannot create dataset {}/{}", path_, name));
  if (!data.empty() && H5Dwrite(dataset.get(), type.get(), H5S_ALL, H5S_ALL, H5P_DEFAULT, pointers.data()) < 0) {
    Fail(file_, fmt::format("cannot write dataset {}/{}", path_, name));
  }
}

std::vector<std::size_t> Hdf5Group::Shape(const std::string& name) const {
  Hdf5Id dataset(H5Dopen2(id_.get(), name.c_str(), H5P_DEFAULT));
  if (!dataset.valid()) Fail(file_, fmt::format("no dataset {}/{}", path_, name));
  Hdf5Id space(H5Dget_space(dataset.get()));
  const int rank = H5Sget_simple_extent_ndims(space.get());
  std::vector<hsize_t> dims(static_cast<std::size_t>(std::max(rank, 0)));
  H5Sget_simple_extent_dims(space.get(), dims.data(), nullptr);
  return std::vector<std::size_t>(dims.begin(), dims.end());
}

template <typename T>
std::vector<T> Hdf5Group::Read(const std::string& name, hid_t type) const {
  Hdf5Id dataset(H5Dopen2(id_.get(), name.c_str(), H5P_DEFAULT));
  if (!dataset.valid()) Fail(file_, fmt::format("no dataset {}/{}", path_, name));
  Hdf5Id space(H5Dget_space(dataset.get()));
  const hssize_t count = H5Sget_simple_extent_npoints(space.get());
  std::vector<T> data(static_cast<std::size_t>(std::max<hssize_t>(count, 0)));
  if (!data.empty() && H5Dread(dataset.get(), type, H5S_ALL, H5S_ALL, H5P_DEFAULT, data.data()) < 0) {
    Fail(file_, fmt::format("cannot read dataset {}/{}", path_, name));
  }
  return data;
}

std::vector<std::int64_t> Hdf5Group::ReadInt64(const std::string& name) const { return Read<std::int64_t>(name, H5T_NATIVE_INT64); }
std::vector<std::uint32_t> Hdf5Group::ReadUInt32(const std::string& name) const { return Read<std::uint32_t>(name, H5T_NATIVE_UINT32); }
std::vector<std::uint8_t> Hdf5Group::ReadUInt8(const std::string& name) const { return Read<std::uint8_t>(name, H5T_NATIVE_UINT8); }
std::vector<double> Hdf5Group::ReadDouble(const std::string& name) const { return Read<double>(name, H5T_NATIVE_DOUBLE); }

std::vector<std::string> Hdf5Group::ReadStrings(const std::string& name) const {
  Hdf5Id dataset(H5Dopen2(id_.get(), name.c_str(), H5P_DEFAULT));
  if (!dataset.valid()) Fail(file_, fmt::format("no dataset {}/{}", path_, name));
  Hdf5Id space(H5Dget_space(dataset.get()));
  const hssize_t count = H5Sget_simple_extent_npoints(space.get());
  std::vector<char*> pointers(static_cast<std::size_t>(std::max<hssize_t>(count, 0)), nullptr);
  Hdf5Id type(H5Tcopy(H5T_C_S1));
  H5Tset_size(type.get(), H5T_VARIABLE);
  H5Tset_cset(type.get(), H5T_CSET_UTF8);
  if (!pointers.empty() && H5Dread(dataset.get(), type.get(), H5S_ALL, H5S_ALL, H5P_DEFAULT, pointers.data()) < 0) {
    Fail(file_, fmt::format("cannot read dataset {}/{}", path_, name));
  }
  std::vector<std::string> out;
  for (char* p : pointers) out.emplace_back(p != nullptr ? p : "");
  if (!pointers.empty()) H5Dvlen_reclaim(type.get(), space.get(), H5P_DEFAULT, pointers.data());
  return out;
}

namespace {

constexpr std::uint64_t kFnvOffset = 0xcbf29ce484222325ull;
constexpr std::uint64_t kFnvPrime = 0x100000001b3ull;

void Fnv(std::uint64_t& h, const void* data, std::size_t size) {
  const auto* bytes = static_cast<const unsigned char*>(data);
  for (std::size_t i = 0; i < size; ++i) {
    h ^= bytes[i];
    h *= kFnvPrime;
  }
}

void HashGroup(const Hdf5Group& group, const std::string& prefix, std::uint64_t& h) {
  for (const std::string& name : group.Children()) {
    const std::string path = prefix + "/" + name;
    H5O_info_t info;
    if (H5Oget_info_by_name2(group.id(), name.c_str(), &info, H5O_INFO_BASIC, H5P_DEFAULT) < 0) {
      Fail(group.file(), fmt::format("cannot inspect {}", path));
    }
    if (info.type == H5O_TYPE_GROUP) {
      HashGroup(group.OpenGroup(name), path, h);
      continue;
    }
    if (info.type != H5O_TYPE_DATASET) continue;
    Fnv(h, path.data(), path.size() + 1);
    for (const std::size_t d : group.Shape(name)) {
      const std::uint64_t d64 = d;
      Fnv(h, &d64, sizeof(d64));
    }
    Hdf5Id dataset(H5Dopen2(group.id(), name.c_str(), H5P_DEFAULT));
    Hdf5Id stored(H5Dget_type(dataset.get()));
    if (H5Tis_variable_str(stored.get()) > 0) {
      for (const std::string& s : group.ReadStrings(name)) Fnv(h, s.c_str(), s.size() + 1);
      continue;
    }
    Hdf5Id native(H5Tget_native_type(stored.get(), H5T_DIR_ASCEND));
    Hdf5Id space(H5Dget_space(dataset.get()));
    const std::size_t count = static_cast<std::size_t>(std::max<hssize_t>(0, H5Sget_simple_extent_npoints(space.get())));
    std::vector<unsigned char> bytes(count * H5Tget_size(native.get()));
    if (!bytes.empty() && H5Dread(dataset.get(), native.get(), H5S_ALL, H5S_ALL, H5P_DEFAULT, bytes.data()) < 0) {
      Fail(group.file(), fmt::format("cannot read {}", path));
    }
    Fnv(h, bytes.data(), bytes.size());
  }
}

void WriteAttribute(hid_t object, const std::string& file, const std::string& where,
                    const std::string& name, hid_t type, const void* value) {
  Hdf5Id space(H5Screate(H5S_SCALAR));
  if (H5Aexists(object, name.c_str()) > 0) H5Adelete(object, name.c_str());
  Hdf5Id attribute(H5Acreate2(object, name.c_str(), type, space.get(), H5P_DEFAULT, H5P_DEFAULT));
  if (!attribute.valid() || H5Awrite(attribute.get(), type, value) < 0) {
    Fail(file, fmt::format("cannot write attribute {}@{}", where, name));
  }
}

void WriteStringAttribute(hid_t object, const std::string& file, const std::string& where,
                          const std::string& name, const std::string& value) {
  Hdf5Id type(H5Tcopy(H5T_C_S1));
  H5Tset_size(type.get(), H5T_VARIABLE);
  H5Tset_cset(type.get(), H5T_CSET_UTF8);
  const char* text = value.c_str();
  WriteAttribute(object, file, where, name, type.get(), &text);
}

}  // namespace

void Hdf5Group::SetAttribute(const std::string& name, const std::string& value) const {
  WriteStringAttribute(id_.get(), file_, path_, name, value);
}
void Hdf5Group::SetAttribute(const std::string& name, std::int64_t value) const {
  WriteAttribute(id_.get(), file_, path_, name, H5T_NATIVE_INT64, &value);
}
void Hdf5Group::SetAttribute(const std::string& name, double value) const {
  WriteAttribute(id_.get(), file_, path_, name, H5T_NATIVE_DOUBLE, &value);
}
void Hdf5Group::SetDatasetAttribute(const std::string& dataset, const std::string& name,
                                    const std::string& value) const {
  Hdf5Id id(H5Dopen2(id_.get(), dataset.c_str(), H5P_DEFAULT));
  if (!id.valid()) Fail(file_, fmt::format("no dataset {}/{}", path_, dataset));
  WriteStringAttribute(id.get(), file_, path_ + "/" + dataset, name, value);
}

std::uint64_t Hdf5Group::ContentHash() const {
  std::uint64_t h = kFnvOffset;
  HashGroup(*this, "", h);
  return h;
}

bool Hdf5Group::HasAttribute(const std::string& name) const {
  return H5Aexists(id_.get(), name.c_str()) > 0;
}

std::string Hdf5Group::StringAttribute(const std::string& name) const {
  Hdf5Id attribute(H5Aopen(id_.get(), name.c_str(), H5P_DEFAULT));
  if (!attribute.valid()) Fail(file_, fmt::format("no attribute {}@{}", path_, name));
  Hdf5Id type(H5Tcopy(H5T_C_S1));
  H5Tset_size(type.get(), H5T_VARIABLE);
  H5Tset_cset(type.get(), H5T_CSET_UTF8);
  char* text = nullptr;
  if (H5Aread(attribute.get(), type.get(), &text) < 0) Fail(file_, fmt::format("cannot read {}@{}", path_, name));
  std::string value(text != nullptr ? text : "");
  H5free_memory(text);
  return value;
}

std::int64_t Hdf5Group::Int64Attribute(const std::string& name) const {
  Hdf5Id attribute(H5Aopen(id_.get(), name.c_str(), H5P_DEFAULT));
  std::int64_t value = 0;
  if (!attribute.valid() || H5Aread(attribute.get(), H5T_NATIVE_INT64, &value) < 0) {
    Fail(file_, fmt::format("cannot read attribute {}@{}", path_, name));
  }
  return value;
}

double Hdf5Group::DoubleAttribute(const std::string& name) const {
  Hdf5Id attribute(H5Aopen(id_.get(), name.c_str(), H5P_DEFAULT));
  double value = 0.0;
  if (!attribute.valid() || H5Aread(attribute.get(), H5T_NATIVE_DOUBLE, &value) < 0) {
    Fail(file_, fmt::format("cannot read attribute {}@{}", path_, name));
  }
  return value;
}

Hdf5File::Hdf5File(Hdf5Id file, std::string path)
    : path_(std::move(path)), file_(std::move(file)) {
  Hdf5Id root(H5Gopen2(file_.get(), "/", H5P_DEFAULT));
  if (!root.valid()) Fail(path_, "cannot open the root group");
  root_ = Hdf5Group(std::move(root), "/", path_);
}

Hdf5File Hdf5File::Create(const std::filesystem::path& path) {
  Hdf5Id create(H5Pcreate(H5P_FILE_CREATE));
  Hdf5Id access(H5Pcreate(H5P_FILE_ACCESS));
  // The oldest format that has what tofu writes: readable by every h5py since 2.x.
  H5Pset_libver_bounds(access.get(), H5F_LIBVER_EARLIEST, H5F_LIBVER_V18);
  Hdf5Id id(H5Fcreate(path.c_str(), H5F_ACC_TRUNC, create.get(), access.get()));
  if (!id.valid()) Fail(path.string(), "cannot create the file");
  return Hdf5File(std::move(id), path.string());
}

Hdf5File Hdf5File::OpenReadOnly(const std::filesystem::path& path) {
  Hdf5Id id(H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT));
  if (!id.valid()) Fail(path.string(), "cannot open (missing, or not an HDF5 file)");
  return Hdf5File(std::move(id), path.string());
}

void Hdf5File::CopyFrom(const Hdf5File& source, const std::string& source_path,
                        const std::string& dest_path) const {
  Hdf5Id lcpl(H5Pcreate(H5P_LINK_CREATE));
  H5Pset_create_intermediate_group(lcpl.get(), 1);
  if (H5Ocopy(source.file_.get(), source_path.c_str(), file_.get(), dest_path.c_str(), H5P_DEFAULT,
              lcpl.get()) < 0) {
    Fail(path_, fmt::format("cannot copy {}:{} to {}", source.path_, source_path, dest_path));
  }
}

void Hdf5File::Close() {
  root_ = Hdf5Group();
  if (!file_.valid()) return;
  const hid_t id = file_.get();
  if (H5Fflush(id, H5F_SCOPE_GLOBAL) < 0) Fail(path_, "cannot flush");
  Hdf5Id closed(std::move(file_));
}

}  // namespace tofu::corpus
