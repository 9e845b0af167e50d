// The VLAD encoding's two products, compiled for the build machine's instruction set (CMake
// HSCLOC_KERNEL_ARCH), as model/dense_kernels.h is and for the same reasons: its Eigen lives in a
// namespace of its own, this header exposes plain arrays only, and the kernels are
// single-threaded (callers split rows across threads).
//
// A query's global descriptor reads the whole whitening projection (2,048 x 16,384 floats, 134
// MB), a pass bound by memory bandwidth: it is kept in half precision, half the bytes.
#pragma once

#include <cstdint>
#include <vector>

namespace hscloc::vlad_kernels {

// A matrix in half precision, each row divided by its largest magnitude first (kept in
// `scales`), so that no row's entries fall below the half format's normal range whatever its
// scale: a whitening row's scale is the inverse of its direction's standard deviation.
struct HalfPrecisionRows {
  int64_t rows = 0;
  int64_t columns = 0;
  std::vector<uint16_t> values;  // rows x columns, IEEE 754 binary16 bits
  std::vector<float> scales;     // rows
};
HalfPrecisionRows ToHalfPrecisionRows(const float* row_major, int64_t rows, int64_t columns);

// out[r - first_row] = <row r, x> for r in [first_row, end_row), x of `columns` floats; each
// result summed in one fixed order wherever its row range begins.
void HalfPrecisionRowsTimes(const HalfPrecisionRows& matrix, const float* x, int64_t first_row,
                            int64_t end_row, float* out);

// For each of `count` descriptors (rows of `dim` floats), the word maximizing
// <centroid, descriptor> - half_squared_norms[word] over `words` centroids (rows of `dim`
// floats): the nearest centroid. Ties go to the lower word.
void NearestWords(const float* descriptors, int64_t count, const float* centroids,
                  const float* half_squared_norms, int64_t words, int64_t dim, int32_t* nearest);

}  // namespace hscloc::vlad_kernels
