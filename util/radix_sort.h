// A stable sort of (key, value) pairs by a non-negative integer key, in linear time.
#pragma once

#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

#include "util/check.h"

namespace hscloc {

// Sorts `items` by key, equal keys keeping their order: least significant digit first, 11 bits a
// pass, as many passes as the largest key has digits (none when every key is 0). `scratch` is
// reused between calls. On items that come in increasing value order this is the order of
// std::sort over the pairs, without its comparisons: the network sorts its rows by conditioning
// key once per level of every query.
inline void StableSortByKey(std::vector<std::pair<int64_t, int64_t>>& items,
                            std::vector<std::pair<int64_t, int64_t>>& scratch) {
  constexpr int kDigitBits = 11;
  constexpr int64_t kDigitMask = (int64_t{1} << kDigitBits) - 1;
  int64_t largest = 0;
  for (const auto& item : items) {
    THROW_CHECK_MSG(item.first >= 0, "StableSortByKey: key {} is negative", item.first);
    largest = std::max(largest, item.first);
  }
  scratch.resize(items.size());
  std::array<size_t, size_t{1} << kDigitBits> starts;
  for (int shift = 0; shift < 63 && (largest >> shift) != 0; shift += kDigitBits) {
    starts.fill(0);
    for (const auto& item : items) ++starts[(item.first >> shift) & kDigitMask];
    size_t start = 0;
    for (size_t& digit_start : starts) start += std::exchange(digit_start, start);
    for (const auto& item : items) scratch[starts[(item.first >> shift) & kDigitMask]++] = item;
    items.swap(scratch);
  }
}

}  // namespace hscloc
