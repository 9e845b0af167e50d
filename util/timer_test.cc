#include "util/timer.h"
#include <gtest/gtest.h>
