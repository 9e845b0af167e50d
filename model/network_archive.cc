// The network's archive: shape, options and weights in a libtorch archive, with a format magic
// and version so that another file or an older format is named, not misread.
#include <fmt/ranges.h>

#include <cmath>
#include <istream>
#include <ostream>
#include <sstream>
#include <string>
#include <vector>

#include "map/map_blobs.h"
#include "model/network.h"
#include "model/network_module.h"
#include "util/binary_io.h"
#include "util/check.h"

namespace hscloc {
namespace {

constexpr int64_t kFormatMagic = 0x4e435348;  // "HSCN"
// Version 2 added the trunk's hidden width; version 1 archives have it equal to the channels.
// Version 3 added node conditioning, node output rows and the tree's node counts; older archives
// are the paper's configuration. Version 4 added pooled point rows and masked decoding. Version 5
// stores the weights flat, by parameter name, with the map-sized tables at half precision when
// saved for a bundle. Version 6 added the descriptor shortcut. Version 7 stores no weights for a
// level without a choice, and a bundle's matrices as 8-bit rows (docs/decisions.md). Version 8
// added the shared trunk, stored once under its first level's names; older archives have a
// trunk per level. Version 9 added the point rows' offsets of a network with several rows per
// point; older archives have one. Version 10 scores a point of several rows by their log-sum-exp
// rather than their maximum, each bias starting at -log of its point's rows (Pooling::kBestPoint):
// its 8-bit rows store each bias plus that log, and a version 9 network of several rows per point
// gets the shift on load, so that a point scores the log of its rows' mean exponential.
constexpr int64_t kFormatVersion = 10;
constexpr int64_t kFirstLogSumExpRowsVersion = 10;
constexpr char kPointRowsName[] = "point_rows";
constexpr int64_t kFirstFlatWeightsVersion = 5;
// The per-row scales of a matrix stored as 8-bit rows, under the matrix's name plus this suffix.
constexpr char kRowScalesSuffix[] = ".row_scales";

void WriteInt64Vector(torch::serialize::OutputArchive& archive, const std::string& key,
                      const std::vector<int64_t>& values) {
  archive.write(key, torch::tensor(values, torch::kInt64));
}

std::vector<int64_t> ReadInt64Vector(torch::serialize::InputArchive& archive,
                                     const std::string& key, size_t expected_size,
                                     const std::string& source) {
  torch::Tensor tensor;
  if (!archive.try_read(key, tensor) || tensor.scalar_type() != torch::kInt64 ||
      tensor.dim() != 1 || static_cast<size_t>(tensor.numel()) != expected_size) {
    ThrowInvalidArgument("{}: not an hscloc network archive ('{}' missing or malformed)", source,
                         key);
  }
  tensor = tensor.contiguous();
  return std::vector<int64_t>(tensor.data_ptr<int64_t>(),
                              tensor.data_ptr<int64_t>() + tensor.numel());
}

// log(rows of the point) for each point row, [rows]; empty with one row per point.
torch::Tensor LogRowsOfPoint(const NetworkShape& shape) {
  if (shape.point_row_offsets.empty()) return {};
  torch::Tensor logs = torch::empty({shape.point_row_offsets.back()});
  for (size_t rank = 0; rank + 1 < shape.point_row_offsets.size(); ++rank) {
    const int64_t first = shape.point_row_offsets[rank];
    const int64_t count = shape.point_row_offsets[rank + 1] - first;
    logs.narrow(0, first, count).fill_(std::log(static_cast<double>(count)));
  }
  return logs;
}

// Point rows of several rows per point plus `sign` times LogRowsOfPoint on their biases.
torch::Tensor ShiftPointRowBiases(const NetworkShape& shape, torch::Tensor rows, double sign) {
  const torch::Tensor logs = LogRowsOfPoint(shape);
  if (!logs.defined()) return rows;
  rows = rows.clone();
  rows.select(1, rows.size(1) - 1).add_(logs.to(rows.device()), sign);
  return rows;
}

// Every parameter and buffer by its dotted name. With kInt8Rows each matrix (a parameter of two
// dimensions: dense weights and the tables with a row per image, node or point) is stored as 8-bit
// rows and their scales; vectors (biases, scales) and buffers stay at full precision, as does a
// matrix holding a value that is not finite.
void WriteWeights(const HscNet& module, const NetworkShape& shape, WeightStorage storage,
                  torch::serialize::OutputArchive& weights) {
  for (const auto& item : module->named_parameters()) {
    const std::string& name = item.key();
    const torch::Tensor stored = item.value().detach().cpu();
    if (storage == WeightStorage::kInt8Rows && stored.dim() == 2 &&
        torch::isfinite(stored).all().item<bool>()) {
      // A bias of -log(rows) would set its row's 8-bit scale and leave the weights a fraction of
      // their precision; stored plus that log, it is near the weights' size.
      const Int8Rows rows =
          QuantizeRows(name == kPointRowsName ? ShiftPointRowBiases(shape, stored, 1) : stored);
      weights.write(name, rows.values);
      weights.write(name + kRowScalesSuffix, rows.scales);
    } else {
      weights.write(name, stored);
    }
  }
  for (const auto& item : module->named_buffers()) {
    weights.write(item.key(), item.value().detach().cpu(), /*is_buffer=*/true);
  }
}

// A stored weight as fp32: 8-bit rows times their scales, half precision converted.
torch::Tensor StoredWeight(torch::serialize::InputArchive& weights, const std::string& name,
                           torch::Tensor stored, const std::string& source) {
  if (stored.scalar_type() == torch::kInt8) {
    Int8Rows rows{std::move(stored), {}};
    if (!weights.try_read(name + kRowScalesSuffix, rows.scales) ||
        rows.scales.scalar_type() != torch::kFloat32 || rows.values.dim() != 2 ||
        rows.scales.sizes() != torch::IntArrayRef{rows.values.size(0)}) {
      ThrowInvalidArgument("{}: network weight '{}' is stored as 8-bit rows without their scales",
                           source, name);
    }
    return DequantizeRows(rows);
  }
  if (!stored.is_floating_point()) {
    ThrowInvalidArgument("{}: network weight '{}' is neither floating point nor 8-bit rows", source,
                         name);
  }
  return stored;
}

// Copies each stored weight into the freshly built module. Archives before version 7 also hold
// weights for levels without a choice, which the module no longer has: they are not read.
void ReadWeights(torch::serialize::InputArchive& weights, const std::string& source,
                 HscNet& module) {
  torch::NoGradGuard no_grad;
  const auto read_into = [&](const std::string& name, torch::Tensor& target, bool is_buffer) {
    torch::Tensor stored;
    if (!weights.try_read(name, stored, is_buffer)) {
      ThrowInvalidArgument("{}: network weights lack '{}'", source, name);
    }
    stored = StoredWeight(weights, name, std::move(stored), source);
    if (stored.sizes() != target.sizes()) {
      ThrowInvalidArgument("{}: network weight '{}' has shape {}, the network needs {}", source,
                           name, fmt::join(stored.sizes(), "x"), fmt::join(target.sizes(), "x"));
    }
    target.copy_(stored);
  };
  for (auto& item : module->named_parameters()) read_into(item.key(), item.value(), false);
  for (auto& item : module->named_buffers()) read_into(item.key(), item.value(), true);
}

}  // namespace

Int8Rows QuantizeRows(const torch::Tensor& matrix) {
  THROW_CHECK_EQ(matrix.dim(), 2);
  const torch::Tensor full = matrix.detach().to(torch::kCPU, torch::kFloat32);
  const torch::Tensor scales = full.abs().amax(1) / 127.0f;
  // A zero row divides by 1 instead of 0: its values are 0 either way.
  const torch::Tensor divisors = torch::where(scales > 0, scales, torch::ones_like(scales));
  const torch::Tensor values =
      (full / divisors.unsqueeze(1)).round().clamp(-127, 127).to(torch::kInt8);
  return {values.contiguous(), scales.contiguous()};
}

torch::Tensor DequantizeRows(const Int8Rows& rows) {
  return rows.values.to(torch::kFloat32) * rows.scales.unsqueeze(1);
}

void NetworkInternals::SaveTo(const Network& network, torch::serialize::OutputArchive& archive,
                              WeightStorage storage) {
  const NetworkShape& shape = network.shape();
  const NetworkOptions& options = network.options();
  WriteInt64Vector(archive, "format", {kFormatMagic, kFormatVersion});
  WriteInt64Vector(archive, "shape",
                   {shape.descriptor_dim, shape.levels, shape.branching, shape.num_images});
  WriteInt64Vector(
      archive, "options",
      {options.channels, options.embedding_dim, options.conditioned_layers, options.trunk_channels,
       options.node_conditioning ? 1 : 0, options.node_output_dim,
       options.pooled_point_rows ? 1 : 0, options.masked_decoding ? 1 : 0,
       options.descriptor_shortcut ? 1 : 0, options.shared_trunk ? 1 : 0});
  WriteInt64Vector(archive, "nodes_per_depth", shape.nodes_per_depth);
  WriteInt64Vector(archive, "point_row_offsets", shape.point_row_offsets);
  torch::serialize::OutputArchive weights;
  WriteWeights(network.impl_->module, shape, storage, weights);
  archive.write("weights", weights);
}

Network NetworkInternals::LoadFrom(torch::serialize::InputArchive& archive,
                                   const std::string& source, ComputeDevice device) {
  const std::vector<int64_t> format = ReadInt64Vector(archive, "format", 2, source);
  if (format[0] != kFormatMagic) {
    ThrowInvalidArgument("{}: not an hscloc network archive (format magic {:#x})", source,
                         format[0]);
  }
  if (format[1] < 1 || format[1] > kFormatVersion) {
    ThrowInvalidArgument(
        "{}: network archive of version {}; this hscloc reads versions 1 to {} (a newer hscloc "
        "wrote it?)",
        source, format[1], kFormatVersion);
  }
  const std::vector<int64_t> s = ReadInt64Vector(archive, "shape", 4, source);
  const size_t option_count = format[1] == 1   ? 3
                              : format[1] == 2 ? 4
                              : format[1] == 3 ? 6
                              : format[1] <= 5 ? 8
                              : format[1] <= 7 ? 9
                                               : 10;
  const std::vector<int64_t> o = ReadInt64Vector(archive, "options", option_count, source);
  NetworkShape shape{static_cast<int>(s[0]),
                     static_cast<int>(s[1]),
                     static_cast<int>(s[2]),
                     static_cast<int>(s[3]),
                     {},
                     {}};
  NetworkOptions options = NetworkOptions::PaperFaithful();
  options.channels = static_cast<int>(o[0]);
  options.embedding_dim = static_cast<int>(o[1]);
  options.conditioned_layers = static_cast<int>(o[2]);
  options.trunk_channels = format[1] == 1 ? options.channels : static_cast<int>(o[3]);
  if (format[1] >= 3) {
    options.node_conditioning = o[4] != 0;
    options.node_output_dim = static_cast<int>(o[5]);
    if (format[1] >= 4) {
      options.pooled_point_rows = o[6] != 0;
      options.masked_decoding = o[7] != 0;
    }
    if (format[1] >= 6) options.descriptor_shortcut = o[8] != 0;
    if (format[1] >= 8) options.shared_trunk = o[9] != 0;
    torch::Tensor nodes;
    if (!archive.try_read("nodes_per_depth", nodes) || nodes.scalar_type() != torch::kInt64 ||
        nodes.dim() != 1) {
      ThrowInvalidArgument("{}: not an hscloc network archive ('nodes_per_depth' malformed)",
                           source);
    }
    nodes = nodes.contiguous();
    shape.nodes_per_depth.assign(nodes.data_ptr<int64_t>(),
                                 nodes.data_ptr<int64_t>() + nodes.numel());
    if (format[1] >= 9) {
      torch::Tensor offsets;
      if (!archive.try_read("point_row_offsets", offsets) ||
          offsets.scalar_type() != torch::kInt64 || offsets.dim() != 1) {
        ThrowInvalidArgument("{}: not an hscloc network archive ('point_row_offsets' malformed)",
                             source);
      }
      offsets = offsets.contiguous();
      shape.point_row_offsets.assign(offsets.data_ptr<int64_t>(),
                                     offsets.data_ptr<int64_t>() + offsets.numel());
    }
  }
  try {
    shape.Check();
    options.Check();
    CheckOptionsFitShape(shape, options);
  } catch (const std::invalid_argument& error) {
    ThrowInvalidArgument("{}: {}", source, error.what());
  }
  auto impl = std::make_unique<Network::Impl>();
  impl->shape = shape;
  impl->options = options;
  impl->module = HscNet(shape, options);
  torch::serialize::InputArchive weights;
  if (!archive.try_read("weights", weights)) {
    ThrowInvalidArgument("{}: network archive without weights", source);
  }
  try {
    if (format[1] >= kFirstFlatWeightsVersion) {
      ReadWeights(weights, source, impl->module);
    } else {
      impl->module->load(weights);
    }
  } catch (const c10::Error& error) {
    ThrowInvalidArgument("{}: network weights do not match shape and options: {}", source,
                         error.what_without_backtrace());
  }
  // Version 10's 8-bit point rows hold each bias plus log of its point's rows (WriteWeights);
  // version 9's were trained for a point's best row and take the shift once.
  torch::Tensor scales;
  if (options.pooled_point_rows &&
      (format[1] < kFirstLogSumExpRowsVersion ||
       weights.try_read(std::string(kPointRowsName) + kRowScalesSuffix, scales))) {
    torch::NoGradGuard no_grad;
    impl->module->point_rows.copy_(ShiftPointRowBiases(shape, impl->module->point_rows, -1));
  }
  Network network(std::move(impl));
  network.SetDevice(device);
  return network;
}

void Network::Save(std::ostream& stream) const {
  torch::serialize::OutputArchive archive;
  NetworkInternals::SaveTo(*this, archive, WeightStorage::kInt8Rows);
  archive.save_to(stream);
}

Network Network::Load(std::istream& stream, const std::string& source, ComputeDevice device) {
  torch::serialize::InputArchive archive;
  try {
    archive.load_from(stream, torch::Device(torch::kCPU));
  } catch (const c10::Error& error) {
    ThrowInvalidArgument("{}: not a network archive: {}", source, error.what_without_backtrace());
  }
  return NetworkInternals::LoadFrom(archive, source, device);
}

Network Network::FromBundle(const MapBundle& bundle, ComputeDevice device) {
  if (!bundle.HasBlob(map_blobs::kNetwork)) {
    ThrowInvalidArgument("map bundle {} holds no trained network (run `hscloc train`)",
                         bundle.dir().string());
  }
  MemoryInputStream stream(bundle.Blob(map_blobs::kNetwork));
  return Load(stream, (bundle.dir() / map_blobs::kNetwork).string(), device);
}

std::vector<float> Network::PointRows(int64_t* width) const {
  const torch::Tensor& rows = impl_->module->point_rows;
  *width = 0;
  if (!rows.defined()) return {};
  const torch::Tensor table = rows.detach().to(torch::kCPU, torch::kFloat32).contiguous();
  *width = table.size(1) - 1;
  const float* data = table.data_ptr<float>();
  return std::vector<float>(data, data + table.numel());
}

bool Network::HasSameWeights(const Network& other) const {
  if (!(shape() == other.shape()) || !(options() == other.options())) return false;
  const auto mine = impl_->module->named_parameters();
  const auto theirs = other.impl_->module->named_parameters();
  if (mine.size() != theirs.size()) return false;
  for (const auto& item : mine) {
    const torch::Tensor* other_parameter = theirs.find(item.key());
    if (other_parameter == nullptr || !torch::equal(item.value().cpu(), other_parameter->cpu())) {
      return false;
    }
  }
  return true;
}

}  // namespace hscloc
