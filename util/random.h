// A small, fast, seedable random generator (xoshiro256**, seeded through SplitMix64) whose
// streams are addressed by keys: Random(seed, {image, keypoint}) gives the same numbers whatever
// the order or the thread in which streams are drawn, so parallel generators stay deterministic.
#pragma once

#include <cmath>
#include <cstdint>
#include <initializer_list>

namespace hscloc {

class Random {
 public:
  explicit Random(uint64_t seed, std::initializer_list<uint64_t> stream_keys = {});

  uint64_t NextU64();
  // Uniform in [0, 1).
  double Uniform() { return (NextU64() >> 11) * 0x1.0p-53; }
  double Uniform(double low, double high) { return low + (high - low) * Uniform(); }
  // Uniform integer in [0, bound), bound > 0 (Lemire's multiply-shift, negligible bias).
  uint64_t UniformInt(uint64_t bound) {
    return static_cast<uint64_t>((static_cast<unsigned __int128>(NextU64()) * bound) >> 64);
  }
  bool Bernoulli(double probability) { return Uniform() < probability; }
  // Standard normal (polar Box-Muller; the second value is kept for the next call).
  double Normal();
  double Normal(double mean, double stddev) { return mean + stddev * Normal(); }

 private:
  uint64_t state_[4];
  bool has_spare_normal_ = false;
  double spare_normal_ = 0;
};

// SplitMix64 finalizer: a well-mixed 64-bit hash of a 64-bit value.
uint64_t MixBits(uint64_t value);

}  // namespace hscloc
