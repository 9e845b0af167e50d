#include "util/half.h"

#include <cmath>
#include <cstring>

namespace hscloc {

uint16_t FloatToHalfBits(float value) {
  uint32_t bits;
  std::memcpy(&bits, &value, sizeof(bits));
  const auto sign = static_cast<uint16_t>((bits >> 16) & 0x8000u);
  const uint32_t magnitude = bits & 0x7fffffffu;
  if (magnitude > 0x7f800000u) return sign | 0x7e00u;   // NaN
  if (magnitude >= 0x477ff000u) return sign | 0x7c00u;  // rounds to at least 65520: inf
  if (magnitude < 0x38800000u) {
    // Below 2^-14, the half subnormals: multiples of 2^-24. Scaling by 2^24 is exact and
    // nearbyint rounds to nearest even; 1024 lands on the smallest normal's bits, as it should.
    return sign | static_cast<uint16_t>(std::nearbyint(std::fabs(value) * 16777216.0f));
  }
  // Round the 23-bit mantissa to 10 bits (to nearest, ties to even); a carry correctly bumps
  // the exponent. Then rebias the exponent from 127 to 15.
  const uint32_t rounded = magnitude + 0xfffu + ((magnitude >> 13) & 1u);
  return sign | static_cast<uint16_t>((rounded - (112u << 23)) >> 13);
}

float HalfBitsToFloat(uint16_t bits) {
  const uint32_t sign = static_cast<uint32_t>(bits & 0x8000u) << 16;
  const uint32_t exponent = (bits >> 10) & 0x1fu;
  const uint32_t mantissa = bits & 0x3ffu;
  if (exponent == 0) {
    // Zero or subnormal: mantissa * 2^-24, exact in float.
    const float magnitude = std::ldexp(static_cast<float>(mantissa), -24);
    return sign ? -magnitude : magnitude;
  }
  uint32_t result;
  if (exponent == 0x1fu) {
    result = sign | 0x7f800000u | (mantissa << 13);  // inf or NaN
  } else {
    result = sign | ((exponent + 112u) << 23) | (mantissa << 13);
  }
  float value;
  std::memcpy(&value, &result, sizeof(value));
  return value;
}

}  // namespace hscloc
