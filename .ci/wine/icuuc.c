/* icuuc.dll for Wine 8.0, which lacks it: Windows 10 (1903 and later) has ICU in System32,
   and Qt 6's Qt6Core.dll (PySide6 6.11) imports ICU's converter functions from it, for
   QStringConverter's encodings other than UTF-8/16/32 and Latin-1. This stand-in has no
   converters: ucnv_open fails with U_FILE_ACCESS_ERROR and lists none, so Qt treats every
   such encoding as unavailable; nmsid uses none (its files are UTF-8). The other imported
   names are only ever called on an open converter; they do nothing. */
#include <stdint.h>

typedef int32_t UErrorCode;
#define U_FILE_ACCESS_ERROR 4

static void fail(UErrorCode *err) { if (err && *err <= 0) *err = U_FILE_ACCESS_ERROR; }

void *ucnv_open(const char *name, UErrorCode *err) { (void)name; fail(err); return 0; }
int32_t ucnv_countAvailable(void) { return 0; }
const char *ucnv_getAvailableName(int32_t n) { (void)n; return 0; }
const char *ucnv_getStandardName(const char *name, const char *standard, UErrorCode *err)
{ (void)name; (void)standard; fail(err); return 0; }
void ucnv_close(void *cnv) { (void)cnv; }

#define NOTHING(name) int32_t name(void) { return 0; }
NOTHING(UCNV_FROM_U_CALLBACK_SUBSTITUTE) NOTHING(UCNV_TO_U_CALLBACK_SUBSTITUTE)
NOTHING(ucnv_cbFromUWriteUChars) NOTHING(ucnv_cbToUWriteUChars)
NOTHING(ucnv_fromUCountPending) NOTHING(ucnv_fromUnicode) NOTHING(ucnv_getFromUCallBack)
NOTHING(ucnv_getMaxCharSize) NOTHING(ucnv_getName) NOTHING(ucnv_getToUCallBack)
NOTHING(ucnv_reset) NOTHING(ucnv_setFromUCallBack) NOTHING(ucnv_setToUCallBack)
NOTHING(ucnv_toUCountPending) NOTHING(ucnv_toUnicode)
