// The real appearance of the synthetic city: its points take the tracks of a descriptor bank,
// and each view the descriptor of the track's view at the same place in the spread of views.
#include <cmath>
#include <numeric>

#include "synthetic/random_streams.h"
#include "synthetic/synthetic_city.h"
#include "util/check.h"
#include "util/random.h"

namespace hscloc {

void SyntheticCity::DealBankTracks() {
  if (bank_->NumTracks() == 0) ThrowInvalidArgument("the descriptor bank holds no track");
  options_.descriptor_dim = static_cast<int>(bank_->dimension());
  // A seeded shuffle (Fisher-Yates): which tracks neighbours share depends on the seed only.
  track_order_.resize(bank_->NumTracks());
  std::iota(track_order_.begin(), track_order_.end(), 0u);
  Random shuffle(options_.seed, {kStreamBankTracks});
  for (size_t i = track_order_.size(); i > 1; --i) {
    std::swap(track_order_[i - 1], track_order_[shuffle.UniformInt(i)]);
  }
}

void SyntheticCity::ComputeViewingReferences() {
  std::vector<Eigen::Vector3d> sums(points_.size(), Eigen::Vector3d::Zero());
  std::vector<size_t> counts(points_.size(), 0);
  for (const SyntheticView& view : database_views_) {
    const Eigen::Vector3d center = CameraCenterInWorld(view.cam_from_world);
    for (const uint32_t p : VisiblePoints(view.camera, view.cam_from_world)) {
      sums[p] += (center - points_[p]).normalized();
      ++counts[p];
    }
  }
  viewing_references_.resize(points_.size());
  viewing_spreads_.resize(points_.size());
  for (size_t p = 0; p < points_.size(); ++p) {
    viewing_references_[p] = sums[p].norm() > 1e-9 ? sums[p].normalized() : point_normals_[p];
    viewing_spreads_[p] = DirectionSpread(sums[p], counts[p]);
  }
}

uint32_t SyntheticCity::TrackOfPoint(uint32_t point_index) const {
  THROW_CHECK_MSG(bank_ != nullptr, "the random appearance has no tracks");
  return track_order_[appearance_of_point_[point_index] % track_order_.size()];
}

uint32_t SyntheticCity::BankViewOfPoint(uint32_t point_index,
                                        const Eigen::Vector3d& camera_center) const {
  const Eigen::Vector3f local =
      LocalViewDirection(camera_center - points_[point_index], viewing_references_[point_index],
                         Eigen::Vector3d::UnitZ());
  return bank_->NearestView(TrackOfPoint(point_index),
                            RelativeViewOffset(local, viewing_spreads_[point_index]));
}

Eigen::VectorXf SyntheticCity::ObservedDescriptorFromBank(uint32_t point_index, uint32_t view,
                                                          bool night) const {
  Eigen::VectorXf descriptor =
      night ? bank_->night().row(view).transpose() : bank_->day().row(view).transpose();
  // A later use of a track is another point: its own fixed offset from the track's appearance.
  const uint32_t appearance = appearance_of_point_[point_index];
  if (appearance >= track_order_.size() && options_.bank_reuse_noise > 0) {
    Random reuse(options_.seed, {kStreamBankReuse, appearance});
    const double per_dimension =
        options_.bank_reuse_noise / std::sqrt(static_cast<double>(descriptor.size()));
    for (int64_t d = 0; d < descriptor.size(); ++d) descriptor[d] += per_dimension * reuse.Normal();
    descriptor.normalize();
  }
  return descriptor;
}

}  // namespace hscloc
