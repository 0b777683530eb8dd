"""The report pages' HTML: what a user's files name reaches a page as text, never markup."""

from hydropump_ctrl import pages


def test_every_cell_title_and_section_is_escaped():
    text = pages.page('<script>t</script>', 'body{}', [
        pages.section('a & <b>', pages.table(['<h>'], [['<img src=x onerror=1>', 3]]))])
    assert '<script>' not in text and '&lt;script&gt;t&lt;/script&gt;' in text
    assert '<img' not in text and '&lt;img src=x onerror=1&gt;' in text
    assert '<h2>a &amp; &lt;b&gt;</h2>' in text and '<th>&lt;h&gt;</th>' in text
    assert '<td>3</td>' in text and text.startswith('<!doctype html>')
