#include "util/parallel.h"
#include <gtest/gtest.h>
