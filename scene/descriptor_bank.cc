#include "scene/descriptor_bank.h"

#include <fmt/format.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <fstream>
#include <limits>
#include <numeric>

#include "util/binary_io.h"
#include "util/check.h"

namespace hscloc {
namespace {

constexpr char kMagic[8] = {'H', 'S', 'C', 'B', 'A', 'N', 'K', '\0'};
constexpr uint32_t kVersion = 1;
// A view direction or descriptor row counts as unit within this much of norm 1 (float16 inputs).
constexpr float kUnitTolerance = 1e-2f;

void WriteCString(std::ostream& stream, const std::string& text) {
  stream.write(text.c_str(), static_cast<std::streamsize>(text.size() + 1));
}

template <typename Matrix>
void WriteRows(std::ostream& stream, const Matrix& rows) {
  WriteBinaryArray(stream, rows.data(), static_cast<size_t>(rows.size()));
}

template <typename Matrix>
void ReadRows(std::istream& stream, Matrix& rows, const std::string& what) {
  ReadBinaryArray(stream, rows.data(), static_cast<size_t>(rows.size()), what);
}

bool RowsAreUnit(const DescriptorMatrix& rows, const std::vector<uint8_t>* mask) {
  for (int64_t i = 0; i < rows.rows(); ++i) {
    if (mask != nullptr && (*mask)[i] == 0) continue;
    if (std::abs(rows.row(i).norm() - 1.0f) > kUnitTolerance) return false;
  }
  return true;
}

}  // namespace

Eigen::Vector3f LocalViewDirection(const Eigen::Vector3d& direction,
                                   const Eigen::Vector3d& reference, const Eigen::Vector3d& up) {
  const Eigen::Vector3d z = reference.normalized();
  // Up projected off the reference; a reference along up (a ground point seen from above) takes
  // any horizontal axis, the same each time.
  Eigen::Vector3d y = up - up.dot(z) * z;
  if (y.norm() < 1e-6) y = z.unitOrthogonal();
  y.normalize();
  const Eigen::Vector3d x = y.cross(z);
  const Eigen::Vector3d unit = direction.normalized();
  return Eigen::Vector3f(static_cast<float>(unit.dot(x)), static_cast<float>(unit.dot(y)),
                         static_cast<float>(unit.dot(z)));
}

float DirectionSpread(const Eigen::Vector3d& sum_of_unit_directions, size_t count) {
  if (count == 0) return 0;
  const double mean = sum_of_unit_directions.norm() / static_cast<double>(count);
  return static_cast<float>(std::sqrt(std::max(0.0, 1.0 - mean * mean)));
}

Eigen::Vector2f RelativeViewOffset(const Eigen::Vector3f& local_direction, float spread) {
  const Eigen::Vector2f offset = local_direction.head<2>();
  return spread > 1e-6f ? Eigen::Vector2f(offset / spread) : offset;
}

DescriptorBank::DescriptorBank(std::string feature, std::vector<std::string> sources,
                               std::vector<uint32_t> track_offsets, DescriptorMatrix day,
                               ViewDirectionMatrix directions, DescriptorMatrix night,
                               std::vector<uint8_t> has_night)
    : feature_(std::move(feature)),
      sources_(std::move(sources)),
      track_offsets_(std::move(track_offsets)),
      day_(std::move(day)),
      directions_(std::move(directions)),
      night_(std::move(night)),
      has_night_(std::move(has_night)) {
  Check();
}

size_t DescriptorBank::NumNightViews() const {
  return static_cast<size_t>(std::count(has_night_.begin(), has_night_.end(), uint8_t{1}));
}

float DescriptorBank::TrackSpread(size_t track) const {
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  for (uint32_t view = FirstView(track); view < EndView(track); ++view) {
    sum += directions_.row(view).transpose().cast<double>();
  }
  return DirectionSpread(sum, EndView(track) - FirstView(track));
}

uint32_t DescriptorBank::NearestView(size_t track, const Eigen::Vector2f& relative_offset) const {
  const float spread = TrackSpread(track);
  uint32_t best = FirstView(track);
  float best_distance = std::numeric_limits<float>::infinity();
  for (uint32_t view = FirstView(track); view < EndView(track); ++view) {
    const float distance =
        (RelativeViewOffset(directions_.row(view).transpose(), spread) - relative_offset)
            .squaredNorm();
    if (distance < best_distance) {
      best_distance = distance;
      best = view;
    }
  }
  return best;
}

DescriptorBank DescriptorBank::Concatenate(const std::vector<DescriptorBank>& banks) {
  if (banks.empty()) ThrowInvalidArgument("no descriptor bank to concatenate");
  std::vector<std::string> sources;
  std::vector<uint32_t> offsets = {0};
  int64_t views = 0;
  for (const DescriptorBank& bank : banks) {
    if (bank.feature() != banks[0].feature() || bank.dimension() != banks[0].dimension()) {
      ThrowInvalidArgument("descriptor banks of {} ({}-D) and {} ({}-D) do not mix",
                           banks[0].feature(), banks[0].dimension(), bank.feature(),
                           bank.dimension());
    }
    sources.insert(sources.end(), bank.sources().begin(), bank.sources().end());
    for (size_t t = 0; t < bank.NumTracks(); ++t) {
      offsets.push_back(static_cast<uint32_t>(views) + bank.EndView(t));
    }
    views += static_cast<int64_t>(bank.NumViews());
  }
  const int64_t dim = banks[0].dimension();
  DescriptorMatrix day(views, dim);
  DescriptorMatrix night(views, dim);
  ViewDirectionMatrix directions(views, 3);
  std::vector<uint8_t> has_night;
  int64_t row = 0;
  for (const DescriptorBank& bank : banks) {
    const auto n = static_cast<int64_t>(bank.NumViews());
    day.middleRows(row, n) = bank.day();
    night.middleRows(row, n) = bank.night();
    directions.middleRows(row, n) = bank.directions();
    has_night.insert(has_night.end(), bank.has_night_.begin(), bank.has_night_.end());
    row += n;
  }
  return DescriptorBank(banks[0].feature(), std::move(sources), std::move(offsets), std::move(day),
                        std::move(directions), std::move(night), std::move(has_night));
}

void DescriptorBank::Save(const std::filesystem::path& path) const {
  const std::filesystem::path partial = path.string() + ".partial";
  {
    std::ofstream stream(partial, std::ios::binary);
    if (!stream) ThrowInvalidArgument("cannot write the descriptor bank {}", partial.string());
    stream.write(kMagic, sizeof(kMagic));
    WriteBinary(stream, kVersion);
    WriteCString(stream, feature_);
    WriteBinary(stream, static_cast<uint64_t>(sources_.size()));
    for (const std::string& source : sources_) WriteCString(stream, source);
    WriteBinary(stream, static_cast<uint64_t>(NumTracks()));
    WriteBinary(stream, static_cast<uint64_t>(NumViews()));
    WriteBinary(stream, static_cast<uint64_t>(dimension()));
    WriteBinaryArray(stream, track_offsets_.data(), track_offsets_.size());
    WriteRows(stream, day_);
    WriteRows(stream, directions_);
    WriteRows(stream, night_);
    WriteBinaryArray(stream, has_night_.data(), has_night_.size());
    if (!stream.flush()) {
      ThrowInvalidArgument("cannot write the descriptor bank {}", partial.string());
    }
  }
  std::filesystem::rename(partial, path);
}

DescriptorBank DescriptorBank::Load(const std::filesystem::path& path) {
  const std::string source = path.string();
  std::ifstream stream(path, std::ios::binary);
  if (!stream) ThrowInvalidArgument("cannot read the descriptor bank {}", source);
  char magic[sizeof(kMagic)] = {};
  stream.read(magic, sizeof(magic));
  if (stream.gcount() != sizeof(magic) || !std::equal(magic, magic + sizeof(magic), kMagic)) {
    ThrowInvalidArgument("{} is not a descriptor bank (hscloc bank)", source);
  }
  const auto version = ReadBinary<uint32_t>(stream, source + ": version");
  if (version != kVersion) {
    ThrowInvalidArgument("{}: descriptor bank version {}, this hscloc reads version {}", source,
                         version, kVersion);
  }
  std::string feature = ReadBinaryCString(stream, source + ": feature");
  const auto num_sources = ReadBinary<uint64_t>(stream, source + ": sources");
  if (num_sources > 10000) ThrowInvalidArgument("{}: corrupt source count", source);
  std::vector<std::string> sources;
  for (uint64_t i = 0; i < num_sources; ++i) {
    sources.push_back(ReadBinaryCString(stream, source + ": source"));
  }
  const auto tracks = ReadBinary<uint64_t>(stream, source + ": tracks");
  const auto views = ReadBinary<uint64_t>(stream, source + ": views");
  const auto dim = ReadBinary<uint64_t>(stream, source + ": dimension");
  if (dim == 0 || dim > 4096 || views > (uint64_t{1} << 32) || tracks > views) {
    ThrowInvalidArgument("{}: corrupt header ({} tracks, {} views, {}-D)", source, tracks, views,
                         dim);
  }
  std::vector<uint32_t> offsets =
      ReadBinaryVector<uint32_t>(stream, tracks + 1, source + ": track offsets");
  if (offsets.back() != views) {
    ThrowInvalidArgument("{}: track offsets end at {}, the bank has {} views", source,
                         offsets.back(), views);
  }
  // The header's counts are checked against the offsets before the matrices are allocated.
  const auto rows = static_cast<int64_t>(views);
  DescriptorMatrix day(rows, static_cast<int64_t>(dim));
  ViewDirectionMatrix directions(rows, 3);
  DescriptorMatrix night(rows, static_cast<int64_t>(dim));
  ReadRows(stream, day, source + ": day descriptors");
  ReadRows(stream, directions, source + ": view directions");
  ReadRows(stream, night, source + ": night descriptors");
  std::vector<uint8_t> has_night = ReadBinaryVector<uint8_t>(stream, views, source + ": night");
  try {
    return DescriptorBank(std::move(feature), std::move(sources), std::move(offsets),
                          std::move(day), std::move(directions), std::move(night),
                          std::move(has_night));
  } catch (const std::invalid_argument& error) {
    ThrowInvalidArgument("{}: {}", source, error.what());
  }
}

void DescriptorBank::Check() const {
  if (feature_.empty()) ThrowInvalidArgument("descriptor bank without a feature name");
  if (track_offsets_.empty() || track_offsets_.front() != 0) {
    ThrowInvalidArgument("descriptor bank track offsets must start at 0");
  }
  for (size_t t = 0; t + 1 < track_offsets_.size(); ++t) {
    if (track_offsets_[t + 1] <= track_offsets_[t]) {
      ThrowInvalidArgument("descriptor bank track {} has no view", t);
    }
  }
  const auto views = static_cast<int64_t>(track_offsets_.back());
  if (day_.rows() != views || night_.rows() != views || directions_.rows() != views ||
      static_cast<int64_t>(has_night_.size()) != views) {
    ThrowInvalidArgument(
        "descriptor bank parts disagree: {} views by the offsets, {} day, {} night, {} "
        "directions, {} night flags",
        views, day_.rows(), night_.rows(), directions_.rows(), has_night_.size());
  }
  if (night_.cols() != day_.cols() || day_.cols() == 0) {
    ThrowInvalidArgument("descriptor bank of {}-D day and {}-D night descriptors", day_.cols(),
                         night_.cols());
  }
  if (!RowsAreUnit(day_, nullptr) || !RowsAreUnit(night_, &has_night_)) {
    ThrowInvalidArgument("descriptor bank descriptors must be unit rows");
  }
  for (int64_t i = 0; i < directions_.rows(); ++i) {
    if (std::abs(directions_.row(i).norm() - 1.0f) > kUnitTolerance) {
      ThrowInvalidArgument("descriptor bank view {} has a direction of norm {}", i,
                           directions_.row(i).norm());
    }
  }
}

bool DescriptorBank::operator==(const DescriptorBank& other) const {
  return feature_ == other.feature_ && sources_ == other.sources_ &&
         track_offsets_ == other.track_offsets_ && day_ == other.day_ &&
         directions_ == other.directions_ && night_ == other.night_ &&
         has_night_ == other.has_night_;
}

}  // namespace hscloc
