// Process-wide allocator settings.
#pragma once

namespace hscloc {

// Keeps freed blocks of up to 32 MB in the process for reuse instead of handing them back to the
// kernel. Training steps and queries allocate and free the same few-megabyte buffers again and
// again; with glibc's defaults every one of them came back as fresh pages, and each first touch
// of a page was a fault the kernel had to zero (half of a training step's CPU time, a tenth of a
// query's network; docs/decisions.md). Idempotent; affects the whole process.
void KeepFreedMemoryForReuse();

}  // namespace hscloc
