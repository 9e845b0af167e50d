#include "util/memory.h"

#include <malloc.h>

namespace hscloc {

void KeepFreedMemoryForReuse() {
  mallopt(M_MMAP_THRESHOLD, 32 << 20);  // glibc's largest: blocks below it come from the heap
  mallopt(M_TRIM_THRESHOLD, 1 << 30);
  mallopt(M_TOP_PAD, 64 << 20);
}

void KeepLargeFreedMemoryForReuse() {
  KeepFreedMemoryForReuse();
  mallopt(M_MMAP_MAX, 0);
}

}  // namespace hscloc
