#include "util/progress_bar.h"
#include <gtest/gtest.h>
