/* The FMI 2.0 logger callback is variadic (printf-style). Stable Rust cannot define a variadic
 * function, so this shim formats the message with vsnprintf and hands the finished string to
 * m1cs_cosim_log_sink, implemented in Rust (crates/cosim/src/logger.rs). */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>

void m1cs_cosim_log_sink(void *env, const char *instance, int status, const char *category,
                         const char *message);

void m1cs_cosim_logger(void *env, const char *instance, int status, const char *category,
                       const char *message, ...) {
    char small[1024];
    va_list ap;
    int n;
    if (message == NULL) {
        m1cs_cosim_log_sink(env, instance, status, category, "(null message)");
        return;
    }
    va_start(ap, message);
    n = vsnprintf(small, sizeof small, message, ap);
    va_end(ap);
    if (n < 0) {
        m1cs_cosim_log_sink(env, instance, status, category, message);
        return;
    }
    if ((size_t)n >= sizeof small) {
        char *big = malloc((size_t)n + 1);
        if (big != NULL) {
            va_start(ap, message);
            vsnprintf(big, (size_t)n + 1, message, ap);
            va_end(ap);
            m1cs_cosim_log_sink(env, instance, status, category, big);
            free(big);
            return;
        }
    }
    m1cs_cosim_log_sink(env, instance, status, category, small);
}
