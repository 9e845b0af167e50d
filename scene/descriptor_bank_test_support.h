// A random descriptor bank for tests of the bank and of what draws from it.
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <string>
#include <vector>

#include "scene/descriptor_bank.h"
#include "util/random.h"

namespace hscloc::testing {

// `tracks` tracks of `min_views` to `min_views` + 2 views: random unit descriptors, random unit
// directions about +z, and a night descriptor on every view but each third one.
inline DescriptorBank RandomDescriptorBank(int tracks, int dim, uint64_t seed, int min_views,
                                           const std::string& source = "test") {
  Random random(seed);
  std::vector<uint32_t> offsets = {0};
  for (int t = 0; t < tracks; ++t) {
    offsets.push_back(offsets.back() + min_views + static_cast<uint32_t>(random.UniformInt(3)));
  }
  const auto views = static_cast<int64_t>(offsets.back());
  DescriptorMatrix day(views, dim), night(views, dim);
  ViewDirectionMatrix directions(views, 3);
  std::vector<uint8_t> has_night(views);
  for (int64_t v = 0; v < views; ++v) {
    for (int d = 0; d < dim; ++d) {
      day(v, d) = static_cast<float>(random.Normal());
      night(v, d) = static_cast<float>(random.Normal());
    }
    day.row(v).normalize();
    night.row(v).normalize();
    has_night[v] = v % 3 != 0;
    if (!has_night[v]) night.row(v).setZero();
    directions.row(v) =
        Eigen::Vector3f(static_cast<float>(random.Normal()), static_cast<float>(random.Normal()),
                        1 + static_cast<float>(std::abs(random.Normal())))
            .normalized()
            .transpose();
  }
  return DescriptorBank("xfeat", {source}, std::move(offsets), std::move(day),
                        std::move(directions), std::move(night), std::move(has_night));
}

}  // namespace hscloc::testing
