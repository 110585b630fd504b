#pragma once
// Error tiers (DESIGN.md, Style 4): bad user input throws a typed exception deriving from
// std::runtime_error whose message names the file/field and says "expected X, got Y";
// algorithm outcomes are fields of a Result; broken internal invariants abort via FT_ASSERT.
#include <cstdio>
#include <cstdlib>
#include <stdexcept>
#include <string>

namespace flashtwin {

/// Base of all user-facing input errors (exit code 2 at the command line).
class InputError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// A file is missing, unreadable or cannot be written.
class IoError : public InputError {
 public:
  using InputError::InputError;
};

/// A configuration file (robot, scenario) has a missing, unknown or malformed field.
class ConfigError : public InputError {
 public:
  using InputError::InputError;
};

/// A command-line or API argument is out of its valid range or malformed.
class ArgumentError : public InputError {
 public:
  using InputError::InputError;
};

}  // namespace flashtwin

/// Internal invariant check: prints the failed condition and aborts (never for user input).
#define FT_ASSERT(cond)                                                                  \
  do {                                                                                   \
    if (!(cond)) {                                                                       \
      std::fprintf(stderr, "flashtwin internal error: %s (%s:%d)\n", #cond, __FILE__, \
                   __LINE__);                                                            \
      std::abort();                                                                      \
    }                                                                                    \
  } while (0)
