#include "util/binary_io.h"
#include <gtest/gtest.h>
