// The checks that scripts/docs_check.py runs in each page of the built site, as WebDriver's
// asynchronous script: its arguments are the window's expected width, how far (px) an element
// may reach past the content column, and the callback, called with the page's problems once its
// images have loaded and MathJax has typeset.
const done = arguments[arguments.length - 1];
const width = arguments[0];
const bleed = arguments[1];
async function settle() {
  for (const img of document.images) {
    if (!img.complete) {
      await new Promise((ok) => {
        img.addEventListener("load", ok);
        img.addEventListener("error", ok);
      });
    }
  }
  if (window.MathJax && MathJax.startup && MathJax.startup.promise) {
    await MathJax.startup.promise;
  }
  await document.fonts.ready;
}
function where(el) {
  let text = el.tagName.toLowerCase();
  if (el.id) text += "#" + el.id;
  const heading = (() => {
    let node = el;
    while (node) {
      let prev = node.previousElementSibling;
      while (prev) {
        if (/^H[1-6]$/.test(prev.tagName)) return prev.textContent.replace("¶", "").trim();
        const inner = prev.querySelectorAll ? prev.querySelectorAll("h1,h2,h3,h4,h5,h6") : [];
        if (inner.length) return inner[inner.length - 1].textContent.replace("¶", "").trim();
        prev = prev.previousElementSibling;
      }
      node = node.parentElement;
    }
    return "";
  })();
  const snippet = (el.textContent || el.getAttribute("src") || "").trim().replace(/\s+/g, " ");
  return `${text} "${snippet.slice(0, 60)}"` + (heading ? ` under "${heading.slice(0, 50)}"` : "");
}
function check() {
  const problems = [];
  // Images and resources: every image has pixels, everything came from the site and was there.
  if (window.innerWidth !== width) {
    problems.push(`window is ${window.innerWidth} px wide, not ${width}`);
  }
  for (const img of document.images) {
    if (!img.complete || img.naturalWidth === 0) {
      problems.push(`broken image ${img.getAttribute("src")}`);
    }
  }
  const origin = location.origin;
  for (const entry of performance.getEntriesByType("resource")) {
    if (!entry.name.startsWith(origin) && !entry.name.startsWith("data:")) {
      problems.push(`resource from outside the site: ${entry.name}`);
    } else if (entry.responseStatus >= 400 && !entry.name.endsWith("/favicon.ico")) {
      problems.push(`resource missing (${entry.responseStatus}): ${entry.name.slice(origin.length)}`);
    }
  }
  // Maths: every maths element typeset, no MathJax error, no TeX delimiter left in the text
  // outside code (where a page may show TeX as TeX).
  for (const el of document.querySelectorAll(".math")) {
    if (!el.querySelector("mjx-container")) problems.push(`maths not typeset: ${where(el)}`);
  }
  for (const el of document.querySelectorAll("mjx-merror")) {
    problems.push(`MathJax error: ${el.getAttribute("data-mjx-error") || where(el)}`);
  }
  const skip = "pre, code, script, style, textarea, mjx-container, .highlight";
  const walker = document.createTreeWalker(document.body, NodeFilter.SHOW_TEXT);
  for (let node = walker.nextNode(); node; node = walker.nextNode()) {
    if (node.parentElement.closest(skip)) continue;
    const found = node.textContent.match(/\\\(|\\\)|\\\[|\\\]|\$\$/);
    if (found) problems.push(`raw TeX "${found[0]}" in: ${where(node.parentElement)}`);
  }
  // Widths: the page fits the window, and nothing in the content is clipped or runs past it.
  const root = document.documentElement;
  if (root.scrollWidth > root.clientWidth) {
    problems.push(`page is ${root.scrollWidth} px wide in a ${root.clientWidth} px window`);
  }
  // The content column's right edge, and the few pixels the theme lets headings and table
  // wrappers bleed past it on purpose (furo: a margin of -0.5rem), inside the page's padding.
  const content = document.querySelector("article") || document.body;
  const right = content.getBoundingClientRect().right + bleed;
  // A code block may scroll inside its box, which must itself fit; what is inside it, or inside
  // typeset maths, is not looked at on its own. An element past the column is reported, not its
  // children.
  const scrolls = "pre, .highlight";
  const inside = "pre *, .highlight *, mjx-container *";
  const flagged = [];
  for (const el of content.querySelectorAll("*")) {
    if (el.closest(inside) || flagged.some((f) => f.contains(el))) continue;
    const style = getComputedStyle(el);
    if (style.display === "none" || style.visibility === "hidden") continue;
    const box = el.getBoundingClientRect();
    if (box.width === 0) continue;
    const clips = style.overflowX !== "visible" && !(el instanceof HTMLImageElement);
    if (clips && !el.matches(scrolls) && el.scrollWidth > el.clientWidth + 1) {
      problems.push(`clipped, ${el.scrollWidth} px in a ${el.clientWidth} px box: ${where(el)}`);
      flagged.push(el);
    } else if (box.right > right + 1) {
      problems.push(`runs ${Math.round(box.right - right)} px past the content column: ${where(el)}`);
      flagged.push(el);
    }
  }
  // An option flag on one line.
  for (const el of content.querySelectorAll("code")) {
    const text = el.textContent.trim();
    if (/^--[a-z]/.test(text) && !/\s/.test(text) && el.getClientRects().length > 1) {
      problems.push(`flag broken over lines: ${text}`);
    }
  }
  return problems;
}
settle().then(() => done(check()), (error) => done([`page script failed: ${error}`]));
