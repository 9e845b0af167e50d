#include "util/check.h"
#include <gtest/gtest.h>
