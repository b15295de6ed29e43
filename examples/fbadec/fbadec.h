/* fbadec - an independent decoder for the MPEG-4 face-object (FAP) stream.
 * Written from the project's specification text only (see NOTES.md). C11, no dependencies. */
#ifndef FBADEC_H
#define FBADEC_H

#include <stddef.h>
#include <stdint.h>

#define FBA_NFAP 68
#define FBA_NHIGH 10
#define FBA_MAX_FRAMES 100000 /* hostile-input bound on decoded frames (see NOTES.md) */

enum fba_status { FBA_FREE = 0, FBA_SET = 1, FBA_RETAINED = 2, FBA_DERIVED = 3 };

/* Order of the high-level fields in fba_frame.high. */
enum fba_high {
    FBA_VISEME_SELECT1, FBA_VISEME_SELECT2, FBA_VISEME_BLEND, FBA_VISEME_DEF,
    FBA_EXPR_SELECT1, FBA_EXPR_INTENSITY1, FBA_EXPR_SELECT2, FBA_EXPR_INTENSITY2,
    FBA_INIT_FACE, FBA_EXPR_DEF
};

typedef struct {
    int64_t frame_number;
    double time_ms;
    int is_intra;
    int fap_quant;
    int coding_type;          /* 0 arithmetic, 1 DCT segment */
    int64_t bit_offset;       /* offset of the plane's is_intra bit */
    int32_t value[FBA_NFAP];  /* index i = FAP i+1; columns 0 and 1 stay 0 */
    uint8_t status[FBA_NFAP]; /* enum fba_status; columns 0/1 = viseme / expression */
    int32_t high[FBA_NHIGH];
} fba_frame;

typedef struct {
    fba_frame *frames;
    size_t n_frames;
    double frame_rate;        /* first signalled rate, 25 if none (D6) */
    int gender;               /* suggested_gender of the first intra plane */
} fba_result;

typedef struct {
    const char *rule;         /* short rule name, e.g. "bad-stuffing" */
    int64_t bit_offset;
    char message[160];
} fba_error;

/* Decodes one face-object stream. Returns 0 on success (res filled; release with
 * fba_result_free), -1 on an invalid stream (err filled, res empty). */
int fba_decode(const uint8_t *data, size_t len, fba_result *res, fba_error *err);
void fba_result_free(fba_result *res);

#endif
