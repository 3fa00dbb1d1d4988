/* Replays files (or every file of directories) through the fuzz harness: the committed corpus as a
 * regression test (ctest fuzz_corpus_replay, built with gcc and AddressSanitizer/UBSan), and a way to
 * reproduce a crash found by libFuzzer:  fuzz_gcode_replay crash-<hash>  */
#define _POSIX_C_SOURCE 200809L
#include <dirent.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static int run_file(const char *path) {
    FILE *f = fopen(path, "rb");
    uint8_t *data;
    long n;
    if (!f) {
        fprintf(stderr, "cannot open %s\n", path);
        return -1;
    }
    fseek(f, 0, SEEK_END);
    n = ftell(f);
    fseek(f, 0, SEEK_SET);
    data = malloc(n > 0 ? (size_t)n : 1);
    if (!data || (n > 0 && fread(data, 1, (size_t)n, f) != (size_t)n)) {
        fclose(f);
        free(data);
        return -1;
    }
    fclose(f);
    LLVMFuzzerTestOneInput(data, (size_t)n);
    free(data);
    return 0;
}

int main(int argc, char **argv) {
    int k, files = 0;
    for (k = 1; k < argc; k++) {
        struct stat st;
        if (stat(argv[k], &st) != 0) {
            fprintf(stderr, "cannot stat %s\n", argv[k]);
            return 2;
        }
        if (S_ISDIR(st.st_mode)) {
            DIR *d = opendir(argv[k]);
            struct dirent *e;
            if (!d) return 2;
            while ((e = readdir(d))) {
                char path[4096];
                if (e->d_name[0] == '.') continue;
                snprintf(path, sizeof path, "%s/%s", argv[k], e->d_name);
                if (run_file(path) != 0) return 2;
                files++;
            }
            closedir(d);
        } else {
            if (run_file(argv[k]) != 0) return 2;
            files++;
        }
    }
    printf("replayed %d inputs without a crash\n", files);
    return files > 0 ? 0 : 2;
}
