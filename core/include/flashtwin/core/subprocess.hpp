#pragma once
// Child processes without a shell: the program and its arguments are an argument vector, so no
// character in a path (quotes, spaces, ';') is ever interpreted.
#include <sys/types.h>

#include <cstddef>
#include <string>
#include <vector>

namespace flashtwin {

/// A program started with posix_spawnp (searched in PATH, no shell) whose standard input is
/// the write end of a pipe; standard output and error are inherited. The destructor closes the
/// pipe and waits for the child, so no zombie is left behind.
class PipedProcess {
 public:
  /// Starts argv[0] with the arguments argv[1..].
  /// @pre !argv.empty()
  /// @throws IoError naming the program when it cannot be started (e.g. not installed).
  explicit PipedProcess(const std::vector<std::string>& argv);
  ~PipedProcess();
  PipedProcess(const PipedProcess&) = delete;
  PipedProcess& operator=(const PipedProcess&) = delete;

  /// Writes all n bytes to the child's standard input. Returns false when the child has
  /// stopped reading (closed its input or exited); never raises SIGPIPE.
  bool write(const void* data, std::size_t n);

  /// Closes the child's standard input and waits for it. Returns its exit status (0–255), or
  /// 128 + the signal number when a signal ended it. Later calls return the same value.
  int finish();

 private:
  pid_t pid_ = -1;
  int fd_ = -1;
  int status_ = -1;
};

}  // namespace flashtwin
