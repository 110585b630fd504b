#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <limits>

#include "flashtwin/core/format.hpp"
#include "flashtwin/core/random.hpp"

using namespace flashtwin;

// The fast appenders write what printf writes ("%.9g", "%.17g", "%.6f", "%.4f"), byte for byte:
// trajectory CSVs and robot programs must not change with the formatter.
TEST(Format, AppendersMatchPrintf) {
  Rng rng(3);
  std::vector<double> values = {0.0, -0.0, 1.0, -1.0, 0.5, 1e-7, 123456789.0, 1e21, -3.5e-300,
                                std::numeric_limits<double>::infinity(),
                                -std::numeric_limits<double>::infinity(), 0.1, 2.5e-5, 999999.5};
  for (int k = 0; k < 20000; ++k)
    values.push_back((rng.uniform() - 0.5) * std::pow(10.0, rng.uniform(-12, 12)));
  char buf[512];
  for (double v : values) {
    for (int digits : {9, 17}) {
      std::string s;
      append_general(s, v, digits);
      std::snprintf(buf, sizeof buf, "%.*g", digits, v);
      ASSERT_EQ(s, buf) << v;
    }
    for (int decimals : {4, 6}) {
      std::string s;
      append_fixed(s, v, decimals);
      std::snprintf(buf, sizeof buf, "%.*f", decimals, v);
      ASSERT_EQ(s, buf) << v;
    }
  }
  EXPECT_EQ(strf("%d-%s", 7, std::string(2000, 'x').c_str()).size(), 2002u);  // any length
}
