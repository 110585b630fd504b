#include "flashtwin/core/format.hpp"

#include <charconv>
#include <cstdarg>
#include <cstdio>
#include <system_error>

#include "flashtwin/core/errors.hpp"

namespace flashtwin {

std::string strf(const char* fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  va_list again;
  va_copy(again, ap);
  const int n = std::vsnprintf(nullptr, 0, fmt, ap);
  va_end(ap);
  std::string out;
  if (n > 0) {
    out.resize(static_cast<std::size_t>(n) + 1);
    std::vsnprintf(out.data(), out.size(), fmt, again);
    out.resize(static_cast<std::size_t>(n));
  }
  va_end(again);
  return out;
}

namespace {

void append_chars(std::string& out, double v, std::chars_format format, int precision) {
  // 17 significant digits, sign, point, exponent; fixed notation of 1e308 needs ~330.
  char buf[400];
  const auto [end, ec] = std::to_chars(buf, buf + sizeof buf, v, format, precision);
  FT_ASSERT(ec == std::errc());
  out.append(buf, end);
}

}  // namespace

void append_general(std::string& out, double v, int digits) {
  FT_ASSERT(digits >= 1 && digits <= 17);
  append_chars(out, v, std::chars_format::general, digits);
}

void append_fixed(std::string& out, double v, int decimals) {
  FT_ASSERT(decimals >= 0 && decimals <= 17);
  append_chars(out, v, std::chars_format::fixed, decimals);
}

}  // namespace flashtwin
