// The first SIGINT (Ctrl-C) or SIGTERM asks long work to stop cleanly at its next safe point
// instead of killing the process: training after its current step, keeping its checkpoint; the
// pipeline between chunks of photos. The handler then resets, so a second signal kills.
#pragma once

#include <atomic>

namespace hscloc {

// Installs the handler; the flag it sets.
const std::atomic<bool>* StopOnFirstSignal();

}  // namespace hscloc
