// IEEE 754 binary16 (half precision) conversion, for descriptors stored at half size.
#pragma once

#include <cstdint>

namespace hscloc {

// The bits of the nearest half (ties to even); +-inf beyond the half range (>= 65520), NaN stays
// NaN.
uint16_t FloatToHalfBits(float value);
// Exact: every half is a float.
float HalfBitsToFloat(uint16_t bits);

}  // namespace hscloc
