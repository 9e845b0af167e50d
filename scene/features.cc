#include "scene/features.h"

namespace hscloc {

void NormalizeRows(DescriptorMatrix& rows) {
  for (int64_t i = 0; i < rows.rows(); ++i) {
    const float norm = rows.row(i).norm();
    if (norm > 0) rows.row(i) /= norm;
  }
}

DescriptorMatrix UnitRows(DescriptorMatrix rows) {
  NormalizeRows(rows);
  return rows;
}

}  // namespace hscloc
